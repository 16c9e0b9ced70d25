"""Where numba's cache goes (demtool.jitcache) and what `demtool warm` runs."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from demtool import jitcache
from demtool.cli import TOOLS, cli
from demtool.stages import STAGES
from demtool.warm import SGM_VARIANTS, warm_steps


def test_numba_cache_dir_is_honoured(tmp_path):
    chosen = jitcache.choose_cache_dir({"NUMBA_CACHE_DIR": str(tmp_path / "shared")},
                                       package_dir=tmp_path / "missing")
    assert chosen == tmp_path / "shared"


def test_writable_package_keeps_numbas_in_tree_cache(tmp_path):
    assert jitcache.choose_cache_dir({}, package_dir=tmp_path) is None


def test_read_only_package_uses_the_user_cache(tmp_path):
    """A package folder nobody can write in (here: one that does not exist) → XDG cache."""
    environ = {"XDG_CACHE_HOME": str(tmp_path / "xdg")}
    chosen = jitcache.choose_cache_dir(environ, package_dir=tmp_path / "read_only")
    assert chosen == tmp_path / "xdg" / "demtool" / "numba"
    assert chosen.is_dir()


def test_no_home_falls_back_to_the_temporary_directory(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    environ = {"XDG_CACHE_HOME": str(blocker / "below")}  # cannot be created
    chosen = jitcache.choose_cache_dir(environ, package_dir=tmp_path / "read_only")
    assert chosen.name == "numba" and chosen.parent.name.startswith("demtool-")


def test_configure_sets_the_variable_for_children(tmp_path, monkeypatch):
    import numba.core.config

    monkeypatch.setenv("NUMBA_CACHE_DIR", "placeholder")
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(jitcache, "PACKAGE_DIR", tmp_path / "read_only")
    monkeypatch.setattr(numba.core.config, "CACHE_DIR", numba.core.config.CACHE_DIR)
    folder = jitcache.configure()
    assert folder == tmp_path / "demtool" / "numba"
    assert os.environ["NUMBA_CACHE_DIR"] == str(folder)
    assert numba.core.config.CACHE_DIR == str(folder)
    assert str(folder) in jitcache.describe()


def test_cached_kernels_lists_called_kernels_and_skips_inlined_ones():
    import demtool.refine.filters  # noqa: F401  (defines inline="always" helpers)
    import demtool.sgm.aggregate  # noqa: F401

    names = [name for name, _ in jitcache.cached_kernels()]
    assert "demtool.sgm.aggregate.sweep_rows" in names
    assert "demtool.refine.filters._popcount" not in names  # inline="always"
    assert len(names) == len(set(names))


def test_warm_covers_every_stage_and_sgm_cost(tmp_path):
    """A new stage must get a step in demtool.warm (or its kernels compile in users' runs)."""
    steps = warm_steps(tmp_path)
    assert {step[0] for step in steps} == set(STAGES)
    costs = {step[step.index("--cost") + 1] for step in steps if "--cost" in step}
    assert costs == {cost for cost, _ in SGM_VARIANTS}
    from demtool.sgm.matcher import COSTS
    assert set(COSTS) == costs
    assert all(str(tmp_path) in " ".join(step) for step in steps if "--out" in step)


def test_warm_refuses_a_cache_it_cannot_write(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocker / "cache"))
    result = CliRunner().invoke(cli, ["warm"])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert lines[-1].startswith("Error: demtool warm: NUMBA_CACHE_DIR=")
    assert "cannot create or write" in lines[-1]
    assert not (blocker.parent / "cache").exists()


def test_warm_is_a_listed_tool():
    result = CliRunner().invoke(cli, ["--help"])
    assert result.exit_code == 0
    assert "warm" in result.output and TOOLS["warm"].split()[0] in result.output
    result = CliRunner().invoke(cli, ["warm", "--help"])
    assert result.exit_code == 0 and "NUMBA_CACHE_DIR" in result.output


def test_warm_check_reports_the_cache():
    result = CliRunner().invoke(cli, ["warm", "--check"])
    assert result.exit_code == 0, result.output
    assert result.output.startswith("numba cache:")
    assert "kernels cached" in result.output


def test_warm_writes_the_bytecode_of_a_writable_package(tmp_path):
    import importlib.util

    from demtool.warm import compile_bytecode

    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("X = 1\n")
    (package / "sub" / "b.py").write_text("Y = 2\n")
    assert compile_bytecode(package) is True
    for module in (package / "a.py", package / "sub" / "b.py"):
        assert Path(importlib.util.cache_from_source(str(module))).is_file()


def test_warm_leaves_a_read_only_package_alone(tmp_path):
    from demtool.warm import compile_bytecode

    assert compile_bytecode(tmp_path / "missing") is False


def test_warm_names_a_module_that_does_not_compile(tmp_path):
    from demtool.errors import ProcessingError
    from demtool.warm import compile_bytecode

    (tmp_path / "broken.py").write_text("def f(:\n")
    with pytest.raises(ProcessingError, match=f"{tmp_path}: a module does not compile"):
        compile_bytecode(tmp_path)


def test_a_cache_folder_the_user_cannot_write_is_named(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    folder = blocker / "cache"  # cannot be created: numba would skip it
    message = jitcache.unwritable_cache_message({"NUMBA_CACHE_DIR": str(folder)})
    assert message.startswith(f"NUMBA_CACHE_DIR={folder} cannot be written by this user")
    assert "unset NUMBA_CACHE_DIR" in message
    assert jitcache.unwritable_cache_message({"NUMBA_CACHE_DIR": str(tmp_path)}) is None
    assert jitcache.unwritable_cache_message({}) is None


def test_every_command_warns_of_an_unwritable_cache_folder(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocker / "cache"))
    result = CliRunner().invoke(cli, ["sgm", "--help"])
    assert result.exit_code == 0
    assert f"NUMBA_CACHE_DIR={blocker / 'cache'} cannot be written" in result.output


# ------------------------------------------------------------- one compile per kernel
KERNEL_MODULE = """
from numba import njit


@njit(cache=True)
def kernel(x):
    total = 0.0
    for i in range(10):
        total += x * i
    return total
"""

# a process of the chain: times its first call of the kernel and counts numba's compiles
CALLER = """
import json, os, sys, time
import demtool
from demtool import jitcache
from numba.core import event
import kernels

compiles = []
event.register("numba:compile", type("Count", (event.Listener,), {
    "on_start": lambda self, ev: compiles.append(1), "on_end": lambda self, ev: None})())
path = jitcache.lock_path(kernels.kernel._cache)
if sys.argv[1] == "hold":  # lock, say so, compile once stdin closes, then let go
    assert jitcache.acquire(path)
    print("locked", flush=True)
    sys.stdin.read()
    kernels.kernel(1.0)  # compiled and saved to the cache while holding the lock
    print(json.dumps({"released": time.time(), "compiles": len(compiles)}), flush=True)
    jitcache.release(path)
    sys.exit(0)
elif sys.argv[1] == "die":  # lock, then be killed holding it
    assert jitcache.acquire(path)
    print("locked", flush=True)
    os.kill(os.getpid(), 9)
print("ready", flush=True)
start = time.perf_counter()
value = kernels.kernel(1.0)
print(json.dumps({"value": value, "compiles": len(compiles), "loaded": time.time(),
                  "waited": time.perf_counter() - start, "path": path}))
"""


def _caller(tmp_path, *args):
    import subprocess
    import sys

    (tmp_path / "kernels.py").write_text(KERNEL_MODULE)
    (tmp_path / "caller.py").write_text(CALLER)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"),
               PYTHONPATH=os.pathsep.join([str(tmp_path), str(Path(jitcache.__file__).parents[1]),
                                           os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen([sys.executable, str(tmp_path / "caller.py"), *args], env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_a_kernel_compiled_by_another_process_is_waited_for_and_loaded(tmp_path):
    """A process killed holding a kernel's lock leaves none (flock locks die with their
    process).  While another process holds a kernel's lock (to compile it), a process that
    misses the kernel in the cache waits, then loads the saved result instead of compiling
    it again."""
    import json
    import time

    dead = _caller(tmp_path, "die")
    assert dead.stdout.readline().strip() == "locked"
    dead.communicate(timeout=60)
    first = _caller(tmp_path, "hold")  # would wait LOCK_WAIT_S for a stale lock
    assert first.stdout.readline().strip() == "locked"
    second = _caller(tmp_path, "use")
    assert second.stdout.readline().strip() == "ready"  # imported: about to call the kernel
    time.sleep(1.0)  # it is waiting on the lock now (however slow its start-up was)
    assert second.poll() is None  # still waiting for the lock: nothing is cached yet
    held = json.loads(first.communicate("", timeout=120)[0].splitlines()[-1])
    found = json.loads(second.communicate(timeout=120)[0].splitlines()[-1])
    assert held["compiles"] == 1  # the holder compiled it, the waiter did not
    assert found["value"] == 45.0 and found["compiles"] == 0  # loaded from the cache
    assert found["loaded"] >= held["released"]  # only once the first process let go
    assert found["waited"] > 0.9
    assert found["path"].startswith(str(tmp_path / "cache")) and found["path"].endswith(
        ".nbi.lock")


def test_no_lock_where_none_can_be_taken(tmp_path):
    """A cache folder that is missing or not writable, or a kernel without a disk cache:
    no lock, and the process compiles as numba alone would."""
    assert not jitcache.acquire(str(tmp_path / "missing" / "k.nbi.lock"), wait_s=0)
    assert jitcache.lock_path(object()) is None
    path = str(tmp_path / "k.nbi.lock")
    assert jitcache.acquire(path, wait_s=0)
    jitcache.release(path)
    assert jitcache.acquire(path, wait_s=0)  # released: free again
    jitcache.release(path)
