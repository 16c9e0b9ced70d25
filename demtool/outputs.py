"""Output files: atomic writes, output transactions and the checks of output paths.

Re-exported by :mod:`demtool.io` (``io.atomic_path``, ``io.output_transaction``,
``io.check_output_paths``); stages use it through ``demtool.io``.

Three promises, whatever the user types and whatever the disk does:

* **An output never destroys an input or another output.**  :func:`check_output_paths`
  resolves every path (symlinks followed, hard links recognised) and refuses an output
  that is an input or another output, or whose folder cannot be made or written, each
  as one :class:`~demtool.errors.InputError` line naming the path.  A stage declares its
  paths with ``output_transaction(inputs=..., outputs=...)``, which runs the check on
  entry, so a stage that enters it before its work refuses before any work.  Whatever
  a stage forgets to declare, the transaction still refuses two writes to one file and
  a write over a declared input.
* **A filesystem error is one line, not a traceback.**  Every ``OSError`` on the way
  (permission denied, read-only or full disk, a file where a folder should be, a
  folder where a file should be) becomes an InputError naming the output.
* **A failure leaves nothing behind.**  Data go to a hidden temporary file beside the
  target, renamed into place only when the whole transaction succeeds; on failure the
  temporaries and the folders the run created are removed, and a commit that fails
  half-way puts back the files it had already replaced.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import os
import tempfile
import threading
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

from demtool.errors import DemtoolError, InputError, OutputError

PathLike = str | os.PathLike
#: Paths as a sequence, or as a mapping of label (an option name such as ``--out``) to a
#: path or a sequence of paths (a repeatable option); ``None`` entries are skipped.
Paths = (Iterable[PathLike | None] | Mapping[str, PathLike | Iterable[PathLike] | None]
         | None)
#: Environment variable that makes a transaction refuse a write its stage did not declare
#: (``output_transaction(..., declared=True)``); the test suite sets it, so a runner that
#: forgets to declare an output fails its tests instead of escaping the path checks.
CHECK_DECLARED_ENV = "DEMTOOL_CHECK_DECLARED_OUTPUTS"


# --------------------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------------------


def _reason(exc: BaseException) -> str:
    """The OS's words for an error ("permission denied"), lower-case, no path."""
    code = getattr(exc, "errno", None)
    text = os.strerror(code) if code else (str(exc).strip().splitlines() or [""])[0]
    text = text or type(exc).__name__
    return text[:1].lower() + text[1:]


def write_error(path: PathLike, exc: BaseException) -> OutputError:
    """The one-line InputError for a failed write of ``path`` (``exc`` an OSError or GDAL's).

    Names the output, the OS's reason and, when it is another path (a folder, a file in
    the way), the path the OS complained about.
    """
    reason = _reason(exc)
    culprit = getattr(exc, "filename", None)
    code = getattr(exc, "errno", None)
    if code in (errno.EEXIST, errno.ENOTDIR) and culprit:
        reason = f"a file is in the way of the folder {culprit}"
    elif culprit and Path(os.fsdecode(culprit)).name.startswith(f".{Path(path).name}."):
        pass  # our own temporary file: naming it would only confuse
    elif culprit and os.fsdecode(culprit) != os.fspath(path):
        reason = f"{reason}: {os.fsdecode(culprit)}"
    return OutputError(f"{path}: cannot write the output ({reason})")


# --------------------------------------------------------------------------------------
# Output path checks
# --------------------------------------------------------------------------------------


def _entries(paths: Paths) -> list[tuple[str | None, Path]]:
    if paths is None:
        return []
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    items = paths.items() if isinstance(paths, Mapping) else ((None, p) for p in paths)
    entries: list[tuple[str | None, Path]] = []
    for label, value in items:
        if value is None:
            continue
        values = [value] if isinstance(value, (str, os.PathLike)) else value
        entries.extend((label, Path(p)) for p in values if p is not None)
    return entries


def resolve(path: PathLike) -> Path:
    """Absolute path with every symlink followed (the parts that exist)."""
    return Path(os.path.realpath(os.path.expanduser(os.fspath(path))))


def _same_file(a: Path, b: Path) -> bool:
    if resolve(a) == resolve(b):
        return True
    try:  # hard links, bind mounts, case-insensitive file systems
        return os.path.samefile(a, b)
    except OSError:
        return False


def _name(label: str | None, path: Path, default: str) -> str:
    return f"{label} {path}" if label else f"{default} {path}"


def _nearest_existing(folder: Path) -> Path:
    current = folder
    while not os.path.lexists(current) and current != current.parent:
        current = current.parent
    return current


def _probe_writable(folder: Path) -> OSError | None:
    """Create and remove a hidden file in ``folder``; the OSError if that fails.

    ``os.access`` is not enough: it says yes to root in ``/proc`` and on some network
    file systems; only a real create tells the truth.
    """
    if not os.access(folder, os.W_OK | os.X_OK):
        return PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fspath(folder))
    try:
        handle, name = tempfile.mkstemp(prefix=".demtool-probe-", dir=folder)
    except OSError as exc:
        return exc
    os.close(handle)
    with contextlib.suppress(OSError):
        os.unlink(name)
    return None


def _shown(path: Path, resolved: Path) -> Path:
    """``path`` as the user typed it when that names ``resolved`` too, else ``resolved``."""
    return path if resolve(path) == resolved else resolved


def _check_folder(output: Path, folder: Path) -> None:
    """Raise InputError unless ``folder`` exists and is writable, or can be created."""
    existing = _nearest_existing(folder)
    if not existing.is_dir():
        if existing == folder:
            raise InputError(f"{output}: cannot write the output: {folder} is a file, "
                             "not a folder")
        raise InputError(f"{output}: cannot create the folder {folder}: {existing} is a file")
    problem = _probe_writable(existing)
    if problem is not None:
        verb = "write in" if existing == folder else f"create {folder} in"
        raise InputError(f"{output}: cannot {verb} the folder {existing} ({_reason(problem)})")


def check_output_paths(inputs: Paths, outputs: Paths, *, output_dirs: Paths = None) -> None:
    """Refuse, before any work, outputs that would destroy data or cannot be written.

    Parameters
    ----------
    inputs : sequence or mapping of path-like
        The stage's input files (folders allowed).  A mapping's keys label the paths in
        messages (``{"--rectify": "r.npz"}``); ``None`` values are skipped.
    outputs : sequence or mapping of path-like
        The output files the stage will write (sidecars included where they matter).
    output_dirs : sequence or mapping of path-like, optional
        Output folders the stage writes into (created if needed).

    Raises
    ------
    InputError
        One line naming the path: an output that is (after following symlinks, or
        through a hard link) an input or another output; an output file that is an
        existing folder, or an output folder that is an existing file; an output
        whose folder is missing and cannot be created (a file in the way, a read-only
        parent) or exists and cannot be written (permissions, read-only file system,
        ``/proc``).
    """
    sources = _entries(inputs)
    files = _entries(outputs)
    folders = _entries(output_dirs)
    targets = [(label, path, False) for label, path in files] + \
              [(label, path, True) for label, path in folders]
    for index, (label, path, _) in enumerate(targets):
        for in_label, source in sources:
            if _same_file(path, source):
                raise InputError(
                    f"{path}: {label or 'the output'} would overwrite the input "
                    f"{_name(in_label, source, 'file')}; choose another output path")
        for other_label, other, _ in targets[:index]:
            if _same_file(path, other):
                first = other_label or "one output"
                second = label or "another output"
                raise InputError(f"{path}: {first} and {second} name the same file; give "
                                 "each output its own path")
    for label, path in folders:  # folders first: their problem is the one to name
        if path.exists() and not path.is_dir():
            raise InputError(f"{path}: {label or 'the output folder'} is a file, "
                             "expected a folder")
        _check_folder(path, path)
    for label, path in files:
        if path.is_dir():
            raise InputError(f"{path}: {label or 'the output'} is a folder, expected a "
                             "file name")
        _check_folder(path, _shown(path.parent, resolve(path).parent))


# --------------------------------------------------------------------------------------
# Transactions
# --------------------------------------------------------------------------------------


def _make_folder(folder: Path) -> list[Path]:
    """``mkdir -p folder``; the folders it created, outermost first."""
    missing = []
    current = folder
    while not os.path.lexists(current) and current != current.parent:
        missing.append(current)
        current = current.parent
    folder.mkdir(parents=True, exist_ok=True)
    return missing[::-1]


def _remove_folders(folders: list[Path]) -> None:
    """Remove the (empty) folders a failed run created, innermost first."""
    for folder in reversed(folders):
        with contextlib.suppress(OSError):
            folder.rmdir()


class _Transaction:
    def __init__(self, inputs: list[tuple[str | None, Path]],
                 declared: tuple[list[Path], list[Path]] | None = None) -> None:
        self.inputs = inputs
        self.declared = declared  # (output files, output folders), resolved; None: no check
        self.pending: list[tuple[Path, Path]] = []
        self.claimed: dict[Path, Path] = {}
        self.created_folders: list[Path] = []

    def declare(self, outputs: list[tuple[str | None, Path]],
                folders: list[tuple[str | None, Path]]) -> None:
        """Add the outputs of a nested transaction to the ones already declared."""
        if self.declared is not None:
            self.declared[0].extend(resolve(p) for _, p in outputs)
            self.declared[1].extend(resolve(p) for _, p in folders)

    def check_declared(self, final: Path) -> None:
        """With ``CHECK_DECLARED_ENV`` set: refuse a write that was not declared."""
        if self.declared is None or not os.environ.get(CHECK_DECLARED_ENV):
            return
        key = resolve(final)
        files, folders = self.declared
        if key in files or any(folder in key.parents for folder in folders):
            return
        raise InputError(f"{final}: written but not declared as an output of this stage "
                         "(declare it in the runner's StageRun outputs)")

    def claim(self, final: Path) -> None:
        """Refuse a second write to one file, or a write over a declared input."""
        key = resolve(final)
        if key in self.claimed:
            raise InputError(f"{final}: two outputs of this run name the same file "
                             f"({self.claimed[key]} and {final}); give each output its own "
                             "path")
        for label, source in self.inputs:
            if _same_file(final, source):
                raise InputError(f"{final}: the output would overwrite the input "
                                 f"{_name(label, source, 'file')}; choose another output path")
        self.check_declared(final)
        self.claimed[key] = final

    def commit(self) -> None:
        """Rename every temporary into place; on failure undo the renames already done."""
        for _, final in self.pending:
            if final.is_dir():
                raise write_error(final, IsADirectoryError(errno.EISDIR, "is a folder"))
        done: list[tuple[Path, Path | None]] = []  # (final, backup of the file it replaced)
        try:
            for temporary, final in self.pending:
                backup = None
                if final.is_file():
                    backup = final.with_name(f"{temporary.name}.previous")
                    try:
                        os.link(final, backup)
                    except OSError:  # no hard links here: cannot undo this one
                        backup = None
                try:
                    os.replace(temporary, final)
                except OSError as exc:
                    if backup is not None:
                        with contextlib.suppress(OSError):
                            backup.unlink()
                    raise write_error(final, exc) from None
                done.append((final, backup))
        except BaseException:
            for final, backup in reversed(done):
                with contextlib.suppress(OSError):
                    if backup is None:
                        final.unlink()
                    else:
                        os.replace(backup, final)
            self.rollback()
            raise
        for _, backup in done:
            if backup is not None:
                with contextlib.suppress(OSError):
                    backup.unlink()
        self.pending.clear()

    def rollback(self) -> None:
        for temporary, _ in self.pending:
            with contextlib.suppress(OSError):
                temporary.unlink()
        self.pending.clear()
        _remove_folders(self.created_folders)
        self.created_folders.clear()


_current_transaction: contextvars.ContextVar[_Transaction | None] = contextvars.ContextVar(
    "demtool_output_transaction", default=None
)


@contextlib.contextmanager
def output_transaction(inputs: Paths = None, outputs: Paths = None, *,
                       output_dirs: Paths = None, declared: bool = False) -> Iterator[None]:
    """Defer the renames of every write inside the block until it succeeds.

    All files written with :mod:`demtool.io` inside the block appear together at the
    end; if the block raises (or the process is interrupted by SIGINT/SIGTERM, which
    the CLI turns into an exception) none of them appears, the temporaries are removed,
    and so are the folders the block created.

    Parameters
    ----------
    inputs, outputs, output_dirs : sequence or mapping of path-like, optional
        The stage's declared paths (see :func:`check_output_paths`, which runs on
        entry, before the block: enter the transaction before the work so a bad path
        is refused at once).  Writes inside the block are also checked against the
        declared inputs, and two writes to one file are refused, declared or not.
    declared : bool
        ``outputs`` and ``output_dirs`` are the complete list of what the block writes
        (as :class:`demtool.stagerun.StageRun` declares them): with the environment
        variable ``DEMTOOL_CHECK_DECLARED_OUTPUTS`` set (the tests set it), a write of
        any other file is refused, so a forgotten declaration cannot slip past the
        checks above.

    A transaction entered inside another joins it: its paths are checked the same
    way, and its writes are committed (or rolled back) with the outer block's.

    Raises
    ------
    InputError
        A declared or written path fails the checks, or a write or the final renames
        fail (one line naming the path; nothing is left behind).
    """
    check_output_paths(inputs, outputs, output_dirs=output_dirs)
    outer = _current_transaction.get()
    if outer is not None:  # join the enclosing transaction
        outer.inputs.extend(_entries(inputs))
        outer.declare(_entries(outputs), _entries(output_dirs))
        yield
        return
    listed = None
    if declared:
        listed = ([resolve(p) for _, p in _entries(outputs)],
                  [resolve(p) for _, p in _entries(output_dirs)])
    transaction = _Transaction(_entries(inputs), listed)
    token = _current_transaction.set(transaction)
    try:
        yield
    except BaseException:
        transaction.rollback()
        raise
    else:
        transaction.commit()
    finally:
        _current_transaction.reset(token)


_UMASK_SWAP = threading.Lock()


def process_umask() -> int:
    """The process's file-mode creation mask, read without changing it.

    ``os.umask`` can only be read by setting it: done on one thread while another
    creates a file (a tile's raster, GDAL's sidecar), the file would get the
    temporary mask.  Linux (≥ 4.7) shows the mask in ``/proc/self/status``
    (``Umask:`` in octal, proc(5)); elsewhere it is swapped and restored under a
    lock, which keeps concurrent calls of this function from reading each other's 0.

    Returns
    -------
    int
        The mask, e.g. ``0o022``.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_SWAP:
        umask = os.umask(0)
        os.umask(umask)
    return umask


@contextlib.contextmanager
def atomic_path(path: PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it into place when the block succeeds.

    Inside :func:`output_transaction` the move waits for the end of the transaction.

    Parameters
    ----------
    path : path-like
        The final file name.  Its parent folder is created if needed.
    suffix : str, optional
        Suffix of the temporary file (defaults to that of ``path``, so that format
        drivers that look at the extension behave).

    Raises
    ------
    InputError
        The folder cannot be created or written, ``path`` is a folder, the block
        fails with an OSError (disk full, ...), or ``path`` is already an output (or
        a declared input) of the current transaction.  Nothing is left behind.
    """
    final = Path(path)
    transaction = _current_transaction.get()
    if transaction is not None:
        transaction.claim(final)
    suffix = final.suffix if suffix is None else suffix
    created: list[Path] = []
    try:
        created = _make_folder(final.parent)
        if final.is_dir():
            raise IsADirectoryError(errno.EISDIR, "is a folder, expected a file name")
        handle, name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=f".tmp{suffix}",
                                        dir=final.parent)
        os.close(handle)
        # mkstemp creates 0600 files; outputs get the permissions any new file would get.
        os.chmod(name, 0o666 & ~process_umask())
    except OSError as exc:
        _remove_folders(created)
        raise write_error(final, exc) from None
    temporary = Path(name)
    try:
        yield temporary
        if transaction is None:
            os.replace(temporary, final)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            temporary.unlink()
        _remove_folders(created)
        if isinstance(exc, OSError) and not isinstance(exc, DemtoolError):
            raise write_error(final, exc) from None
        raise
    if transaction is not None:
        transaction.pending.append((temporary, final))
        transaction.created_folders.extend(created)
