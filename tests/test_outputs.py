"""demtool.outputs: output path checks, filesystem errors, transactions that leave nothing."""

import errno
import os

import numpy as np
import pytest

from demtool import io as dio
from demtool.errors import InputError, OutputError

ROOT = os.geteuid() == 0


def _tree(folder):
    """Every path under ``folder`` with its bytes (files) or None (folders)."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


@pytest.fixture
def files(tmp_path):
    a = tmp_path / "a.tif"
    a.write_bytes(b"left image")
    b = tmp_path / "b.npz"
    b.write_bytes(b"rectification")
    return tmp_path, a, b


def test_output_over_an_input_is_refused_naming_both(files):
    tmp_path, a, b = files
    with pytest.raises(InputError, match=r"a\.tif: --out would overwrite the input "
                                         r"LEFT .*a\.tif; choose another output path"):
        dio.check_output_paths({"LEFT": a, "--rectify": b}, {"--out": a})
    # A different spelling of the same file is the same file.
    with pytest.raises(InputError, match="would overwrite the input"):
        dio.check_output_paths([a], [tmp_path / "sub" / ".." / "a.tif"])


def test_symlinks_and_hard_links_are_followed(files):
    tmp_path, a, b = files
    link = tmp_path / "link.tif"
    link.symlink_to(a)
    with pytest.raises(InputError, match="would overwrite the input"):
        dio.check_output_paths([a], [link])
    folder_link = tmp_path / "same_folder"
    folder_link.symlink_to(tmp_path)
    with pytest.raises(InputError, match="would overwrite the input"):
        dio.check_output_paths([b], [folder_link / "b.npz"])
    hard = tmp_path / "hard.npz"
    os.link(b, hard)
    with pytest.raises(InputError, match="would overwrite the input"):
        dio.check_output_paths([b], [hard])


def test_two_outputs_on_one_path_are_refused(files):
    tmp_path, _, _ = files
    out = tmp_path / "o.tif"
    with pytest.raises(InputError, match=r"o\.tif: --out and --interpolated-mask name the "
                                         r"same file"):
        dio.check_output_paths([], {"--out": out, "--interpolated-mask": out})
    with pytest.raises(InputError, match="name the same file"):
        dio.check_output_paths([], [out, tmp_path / "." / "o.tif"])


def test_good_paths_pass_and_create_nothing(files):
    tmp_path, a, b = files
    before = _tree(tmp_path)
    dio.check_output_paths({"LEFT": a, "--rectify": b, "--mask": None},
                           {"--out": tmp_path / "new" / "deeper" / "d.tif", "--conf": None},
                           output_dirs=[tmp_path / "scene"])
    assert _tree(tmp_path) == before


def test_unwritable_folders_are_one_line_naming_the_path(files):
    tmp_path, a, _ = files
    # A path under an existing file.
    with pytest.raises(InputError, match=r"cannot create the folder .*a\.tif/sub: .*a\.tif "
                                         r"is a file"):
        dio.check_output_paths([], [a / "sub" / "o.tif"])
    with pytest.raises(InputError, match=r"a\.tif is a file, not a folder"):
        dio.check_output_paths([], [a / "o.tif"])
    # /proc refuses files even to root.
    with pytest.raises(InputError, match=r"/proc/o\.tif: cannot write in the folder /proc"):
        dio.check_output_paths([], ["/proc/o.tif"])
    with pytest.raises(InputError, match=r"cannot create /proc/new in the folder /proc"):
        dio.check_output_paths([], ["/proc/new/o.tif"])
    # The output is a folder; an output folder is a file.
    with pytest.raises(InputError, match="is a folder, expected a file name"):
        dio.check_output_paths([], {"--out": tmp_path})
    with pytest.raises(InputError, match="is a file, expected a folder"):
        dio.check_output_paths([], [], output_dirs={"--out": a})


@pytest.mark.skipif(ROOT, reason="root writes into read-only folders")
def test_read_only_folder_is_refused(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with pytest.raises(InputError, match=r"ro/o\.tif: cannot write in the folder .*ro "
                                             r"\(permission denied\)"):
            dio.check_output_paths([], [folder / "o.tif"])
        with pytest.raises(OutputError, match="permission denied"):
            dio.write_json(folder / "o.json", {"a": 1})
    finally:
        folder.chmod(0o755)
    assert list(folder.iterdir()) == []


def test_read_only_folder_via_the_os_error(tmp_path, monkeypatch):
    """What a read-only folder does to a write (simulated: root ignores permissions)."""
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", str(tmp_path))

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(OutputError, match=r"o\.json: cannot write the output \(permission "
                                          r"denied: .*\)$"):
        dio.write_json(tmp_path / "o.json", {"a": 1})
    with pytest.raises(InputError, match=r"o\.tif: cannot write in the folder .*permission"):
        dio.check_output_paths([], [tmp_path / "o.tif"])
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("writer", ["raster", "npz", "json"])
def test_write_into_a_file_or_proc_is_one_line_and_leaves_nothing(files, writer):
    tmp_path, a, _ = files
    before = _tree(tmp_path)
    write = {
        "raster": lambda p: dio.write_raster(p, np.zeros((4, 4))),
        "npz": lambda p: dio.write_npz(p, "matches", {
            "points_left": np.zeros((2, 2)), "points_right": np.zeros((2, 2)),
            "left_name": "l", "right_name": "r"}),
        "json": lambda p: dio.write_json(p, {"a": 1}),
    }[writer]
    with pytest.raises(OutputError, match=r"cannot write the output \(a file is in the way "
                                          r"of the folder"):
        write(a / "sub" / "o.out")
    with pytest.raises(OutputError, match=r"^/proc/x/o\.out: cannot write the output"):
        write("/proc/x/o.out")
    with pytest.raises(OutputError, match=r"\d: cannot write the output \(is a directory\)"):
        write(tmp_path)
    with pytest.raises(OutputError), dio.output_transaction():
        write(a / "o.out")
    assert _tree(tmp_path) == before


def test_disk_full_during_a_write_is_one_line_and_leaves_nothing(tmp_path, monkeypatch):
    def full(handle, **arrays):
        handle.write(b"partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", full)
    with pytest.raises(OutputError) as caught, dio.output_transaction():
        dio.write_json(tmp_path / "first.json", {"a": 1})
        dio.write_npz(tmp_path / "new" / "m.npz", "matches", {
            "points_left": np.zeros((2, 2)), "points_right": np.zeros((2, 2)),
            "left_name": "l", "right_name": "r"})
    assert str(caught.value).endswith("m.npz: cannot write the output (no space left on "
                                      "device)")
    assert "\n" not in str(caught.value)
    assert list(tmp_path.iterdir()) == []  # also the folder "new" the write made is gone


def test_output_error_is_also_an_os_error_for_tolerant_callers(tmp_path):
    target = tmp_path / "file"
    target.write_text("x")
    with pytest.raises(OSError):
        with dio.atomic_path(target / "cache.npz") as temporary:
            temporary.write_bytes(b"never")


def test_transaction_checks_declared_paths_on_entry(files):
    tmp_path, a, b = files
    ran = []
    with pytest.raises(InputError, match="would overwrite the input"):
        with dio.output_transaction(inputs={"--rectify": b}, outputs={"--out": b}):
            ran.append(True)
    assert ran == []
    assert b.read_bytes() == b"rectification"


def test_transaction_refuses_writes_over_declared_inputs_and_double_writes(files):
    tmp_path, a, b = files
    before = _tree(tmp_path)
    # The sidecar of an undeclared output lands on a declared input.
    sidecar_input = tmp_path / "d.tif.json"
    sidecar_input.write_text("{}")
    before = _tree(tmp_path)
    with pytest.raises(InputError, match=r"d\.tif\.json: the output would overwrite the input "
                                         r"--scene"):
        with dio.output_transaction(inputs={"--scene": sidecar_input}):
            dio.write_raster(tmp_path / "d.tif", np.zeros((3, 3)))
            dio.write_json(tmp_path / "d.tif.json", {})
    assert _tree(tmp_path) == before
    # Two writes to one file (e.g. --out o.tif --albedo-out o.tif), undeclared.
    with pytest.raises(InputError, match=r"o\.tif: two outputs of this run name the same file"):
        with dio.output_transaction():
            dio.write_raster(tmp_path / "o.tif", np.zeros((3, 3)))
            dio.write_raster(tmp_path / "sub" / ".." / "o.tif", np.ones((3, 3)))
    assert _tree(tmp_path) == before


def test_failed_commit_puts_back_what_it_replaced(tmp_path, monkeypatch):
    old = tmp_path / "old.json"
    old.write_text('"previous"\n')
    real_replace = os.replace
    calls = []

    def replace(src, dst):
        calls.append(dst)
        if str(dst).endswith("second.json"):
            raise OSError(errno.EIO, "Input/output error")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OutputError, match=r"second\.json: cannot write the output "
                                          r"\(input/output error\)"):
        with dio.output_transaction():
            dio.write_json(old, "new")
            dio.write_json(tmp_path / "second.json", "new")
    assert old.read_text() == '"previous"\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.json"]


def test_successful_transaction_still_commits_everything(tmp_path):
    with dio.output_transaction(inputs=[], outputs=[tmp_path / "x" / "a.json"]):
        dio.write_json(tmp_path / "x" / "a.json", 1)
        dio.write_json(tmp_path / "x" / "b.json", 2)
    assert dio.read_json(tmp_path / "x" / "a.json") == 1
    assert dio.read_json(tmp_path / "x" / "b.json") == 2
    assert sorted(p.name for p in (tmp_path / "x").iterdir()) == ["a.json", "b.json"]


def test_labels_with_several_paths_are_checked_each(files):
    folder, a, b = files
    with pytest.raises(InputError, match=r"a\.tif: --out would overwrite the input IMAGES "):
        dio.check_output_paths({"IMAGES": [b, a]}, {"--out": [folder / "c.tif", a]})
    with pytest.raises(InputError, match="--out and sidecar name the same file"):
        dio.check_output_paths({}, {"--out": [folder / "c.tif", folder / "d.tif"],
                                    "sidecar": folder / "c.tif"})


def test_nested_transaction_joins_the_outer_one(files):
    folder, a, _ = files
    with pytest.raises(RuntimeError), dio.output_transaction(inputs=[a]):
        dio.write_json(folder / "outer.json", {"x": 1})
        with dio.output_transaction(outputs=[folder / "inner.json"]):
            dio.write_json(folder / "inner.json", {"y": 2})
        assert not (folder / "inner.json").exists()  # waits for the outer block
        raise RuntimeError("fail after the inner block")
    assert not (folder / "outer.json").exists() and not (folder / "inner.json").exists()
    with dio.output_transaction():
        with dio.output_transaction(inputs={"--in": folder / "in.json"}):
            pass
        with pytest.raises(InputError, match="would overwrite the input --in"):
            dio.write_json(folder / "in.json", {})  # the inner declaration still holds
    with dio.output_transaction():
        with dio.output_transaction():
            dio.write_json(folder / "inner.json", {"y": 2})
    assert dio.read_json(folder / "inner.json") == {"y": 2}


def test_undeclared_writes_are_refused_when_checked(files, monkeypatch):
    from demtool.outputs import CHECK_DECLARED_ENV

    folder, _, _ = files
    declared = dict(outputs={"--out": folder / "o.json"}, output_dirs={"--dir": folder / "d"},
                    declared=True)
    monkeypatch.setenv(CHECK_DECLARED_ENV, "1")
    with dio.output_transaction(**declared):
        dio.write_json(folder / "o.json", {})
        dio.write_json(folder / "d" / "any" / "name.json", {})  # inside a declared folder
    before = _tree(folder)
    with pytest.raises(InputError, match=r"extra\.json: written but not declared"), \
            dio.output_transaction(**declared):
        dio.write_json(folder / "o.json", {"new": 1})
        dio.write_json(folder / "extra.json", {})
    assert _tree(folder) == before
    monkeypatch.delenv(CHECK_DECLARED_ENV)
    with dio.output_transaction(**declared):  # users are not refused: the check is for tests
        dio.write_json(folder / "extra.json", {})
    assert (folder / "extra.json").exists()


def test_umask_read_on_threads_never_leaks_a_zero_mask(tmp_path):
    """Outputs written on several threads get the process mask, and the mask stays put.

    ``os.umask`` can only be read by setting it: read that way on one thread while
    another creates a file, the file got mode 0666 and the process could keep mask 0.
    """
    from concurrent.futures import ThreadPoolExecutor

    from demtool.outputs import process_umask

    before = os.umask(0o027)
    try:
        assert process_umask() == 0o027

        def write(index):
            with dio.atomic_path(tmp_path / f"out{index}.bin") as temporary:
                temporary.write_bytes(b"x")
            return (tmp_path / f"out{index}.bin").stat().st_mode & 0o777

        with ThreadPoolExecutor(4) as pool:
            modes = set(pool.map(write, range(200)))
        assert modes == {0o640}
        assert process_umask() == 0o027
    finally:
        os.umask(before)
