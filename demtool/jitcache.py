"""Where numba keeps demtool's compiled kernels, chosen before numba is imported.

Every ``@njit(cache=True)`` kernel compiles the first time it runs and is then read
from numba's on-disk cache.  numba writes that cache beside the source
(``__pycache__``) when the package folder is writable; on a read-only install (a
site-wide or container install, an HPC module) it would fall back to a per-user
folder that ``demtool warm`` run by the administrator never fills.  This module makes
the choice explicit, in this order:

1. ``NUMBA_CACHE_DIR`` when it is set (numba's own setting, honoured as given): point
   it at a shared, writable folder to share one cache between users or batch jobs;
2. beside the package (numba's default) when the package folder is writable;
3. else ``$XDG_CACHE_HOME/demtool/numba`` (``~/.cache/demtool/numba``), or, where
   that cannot be created either (a batch account without a home), a folder of this
   user's in the temporary directory (numba would otherwise refuse to import the
   kernels at all).

:func:`configure` runs from ``demtool/__init__.py``, so it is in place before any
demtool module imports numba.  numba keys each cache entry by the source file's path,
modification time and size and by the CPU (name and features), so a cache filled on
one kind of node is missed (and refilled, where writable) on another.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
ENV = "NUMBA_CACHE_DIR"


def writable(folder: Path) -> bool:
    """True when a file can be created in ``folder`` (numba's own test of a cache folder)."""
    try:
        tempfile.TemporaryFile(dir=folder).close()
    except OSError:
        return False
    return True


def user_cache_dir(environ: dict[str, str] | None = None) -> Path:
    """``$XDG_CACHE_HOME/demtool/numba``, or ``~/.cache/demtool/numba`` without it."""
    environ = os.environ if environ is None else environ
    base = environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "demtool" / "numba"


def usable(folder: Path) -> bool:
    """True when ``folder`` exists or can be created, and is writable."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return writable(folder)


def choose_cache_dir(environ: dict[str, str] | None = None,
                     package_dir: Path | None = None) -> Path | None:
    """The folder numba should cache demtool's kernels in; None = beside the sources.

    Parameters
    ----------
    environ : mapping, optional
        The environment (default ``os.environ``); ``NUMBA_CACHE_DIR`` wins when set.
    package_dir : Path, optional
        The installed ``demtool`` package folder (default :data:`PACKAGE_DIR`).

    Returns
    -------
    Path or None
        ``NUMBA_CACHE_DIR``; None when ``package_dir`` is writable (numba's in-tree
        ``__pycache__``); else :func:`user_cache_dir` (created), or where that cannot
        be created ``<tmp>/demtool-<uid>/numba``.
    """
    environ = os.environ if environ is None else environ
    if environ.get(ENV):
        return Path(environ[ENV])
    if writable(PACKAGE_DIR if package_dir is None else package_dir):
        return None
    folder = user_cache_dir(environ)
    if usable(folder):
        return folder
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return Path(tempfile.gettempdir()) / f"demtool-{uid}" / "numba"


def configure() -> Path | None:
    """Set ``NUMBA_CACHE_DIR`` (for this process and its children) where it is needed.

    Called on ``import demtool``.  When numba is already imported, its configuration is
    updated as well (numba reads the setting when a cached kernel is defined).

    Returns
    -------
    Path or None
        The cache folder in use; None = numba's in-tree ``__pycache__`` folders.
    """
    folder = choose_cache_dir()
    if folder is None or os.environ.get(ENV) == str(folder):
        return folder
    os.environ[ENV] = str(folder)
    numba_config = sys.modules.get("numba.core.config")
    if numba_config is not None:
        numba_config.CACHE_DIR = str(folder)
    return folder


def unwritable_cache_message(environ: dict[str, str] | None = None) -> str | None:
    """A warning when ``NUMBA_CACHE_DIR`` names a folder this user cannot write; else None.

    numba uses a cache folder only where it can write (``UserProvidedCacheLocator``
    tries a temporary file there), also for reading: a shared cache made read-only for
    the users after ``demtool warm`` filled it is skipped, and every user's first runs
    compile the kernels again into numba's own per-user cache.
    """
    environ = os.environ if environ is None else environ
    given = environ.get(ENV)
    if not given or usable(Path(given)):
        return None
    return (f"{ENV}={given} cannot be written by this user, so numba does not use it (not "
            "even to read the kernels `demtool warm` put there): each stage's first run "
            "compiles its kernels again. Make the folder writable for the users (a group "
            f"folder), or unset {ENV} to use your own cache")


def describe() -> str:
    """One line naming the cache folder in use, for logs and ``demtool warm``."""
    folder = choose_cache_dir()
    if folder is None:
        return f"numba cache: beside the sources ({PACKAGE_DIR}/**/__pycache__)"
    source = f"{ENV}" if os.environ.get(ENV) else "user cache"
    return f"numba cache: {folder} ({source})"


def cached_kernels() -> list[tuple[str, bool]]:
    """Every cached numba kernel of the imported demtool modules and whether the cache
    holds compiled code of its current source: (``module.function``, found), by name.

    Kernels inlined into others (``inline="always"``) are left out; those only called
    from other kernels compile as part of their callers and have no entry of their own.
    """
    from numba.core.registry import CPUDispatcher

    found = []
    for name, module in sorted(sys.modules.items()):
        if not (name == "demtool" or name.startswith("demtool.")) or module is None:
            continue
        for attr, value in vars(module).items():
            if not isinstance(value, CPUDispatcher) or value.__module__ != name:
                continue
            cache_file = getattr(getattr(value, "_cache", None), "_cache_file", None)
            if cache_file is None or value.targetoptions.get("inline") == "always":
                continue  # not cache=True, or compiled only inside its callers
            try:  # numba's index: empty when missing or written for an older source file
                entries = cache_file._load_index()
            except Exception:  # noqa: BLE001 - an unreadable index is a missing one
                entries = {}
            found.append((f"{name}.{attr}", bool(entries)))
    return sorted(set(found))


# ---------------------------------------------------------------- one compile per kernel
# Processes started together (``make -j2 demo``, a batch of jobs, Dask workers) often need
# the same kernel while numba's cache holds none of it: each compiled it (a fresh clone's
# demo compiled dem's ``_cell_medians`` in two processes at once, 2 x 9.7 CPU s).  With the
# lock, a process that misses the cache takes a file lock beside the kernel's cache index
# (``<index>.nbi.lock``) and looks again once it holds it: the process that compiled in the
# meantime has saved its result, which is loaded instead of compiled.  The locks are
# ``flock`` locks, which the system drops when their process ends (a killed process leaves
# no lock behind; the lock files themselves stay, empty).  Where no lock can be taken (a
# cache folder this user cannot write, no ``fcntl``, a file system without locks), or after
# :data:`LOCK_WAIT_S`, the process compiles as numba alone would.

#: Longest wait for another process's compile of a kernel, s (a large parallel kernel on a
#: loaded 2-core machine took 200 s); then this process compiles it too.
LOCK_WAIT_S = 600.0
LOCK_SUFFIX = ".lock"
_held: dict[str, int] = {}  # lock file -> descriptor, held by this process


def lock_path(cache: object) -> str | None:
    """The lock file of a numba cache object (``dispatcher._cache``): beside its index;
    None for a kernel without an on-disk cache (``cache=False``)."""
    index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
    return index + LOCK_SUFFIX if isinstance(index, str) else None


def acquire(path: str, wait_s: float | None = None) -> bool:
    """Take the exclusive lock ``path`` for this process, waiting at most ``wait_s``
    (default :data:`LOCK_WAIT_S`); False when it cannot be taken (no folder, no rights, no
    locks on this file system, still held after the wait)."""
    import time

    try:
        import fcntl
    except ImportError:  # not a POSIX system
        return False
    try:
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
    except OSError:
        return False
    deadline = time.monotonic() + (LOCK_WAIT_S if wait_s is None else wait_s)
    pause = 0.01
    while True:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if time.monotonic() >= deadline:
                break
            time.sleep(pause)
            pause = min(2 * pause, 0.2)
            continue
        except OSError:  # ENOLCK and the like: no locks here
            break
        _held[path] = descriptor
        return True
    os.close(descriptor)
    return False


def release(path: str) -> None:
    """Release the lock ``path`` if this process holds it (closing its descriptor drops it)."""
    descriptor = _held.pop(path, None)
    if descriptor is not None:
        os.close(descriptor)


def install_compile_lock() -> bool:
    """Make numba take :func:`acquire`'s lock around each compile of a cached kernel.

    Wraps ``numba.core.caching.Cache.load_overload`` (on a miss: lock, then look again)
    and ``numba.core.dispatcher.Dispatcher.compile`` (the lock is released once the result
    is saved, or the compile failed); both run under numba's own compiler lock, so the
    threads of a process never wait for each other's file locks.  Returns False when this
    numba lacks either (nothing is changed).
    """
    from numba.core import caching, dispatcher
    from numba.core.compiler_lock import global_compiler_lock

    load, compile_ = caching.Cache.load_overload, dispatcher.Dispatcher.compile
    if getattr(compile_, "_demtool_lock", False):
        return True
    if not (callable(load) and callable(compile_)):
        return False

    def load_overload(self, sig, target_context):
        found = load(self, sig, target_context)
        path = lock_path(self)
        if found is not None or path is None or path in _held:
            return found
        if acquire(path):  # another process may have saved it while we waited
            found = load(self, sig, target_context)
            if found is not None:
                release(path)
        return found

    def compile(self, sig):
        with global_compiler_lock:  # re-entrant: kernels called by a kernel compile inside
            path = lock_path(getattr(self, "_cache", None))
            held_before = path in _held
            try:
                return compile_(self, sig)
            finally:
                if path is not None and not held_before:
                    release(path)

    compile._demtool_lock = True
    caching.Cache.load_overload = load_overload
    dispatcher.Dispatcher.compile = compile
    return True


class _NumbaFinder:
    """Installs the compile lock once numba's dispatcher module has been imported."""

    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name != "numba.core.dispatcher":
            return None
        import importlib.machinery

        sys.meta_path[:] = [f for f in sys.meta_path if f is not cls]
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is None or spec.loader is None:
            return spec
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            sys.modules[name] = module  # install_compile_lock imports it by name
            try:
                install_compile_lock()
            except Exception:  # noqa: BLE001 - an unknown numba: it compiles as before
                pass

        spec.loader.exec_module = exec_module
        return spec


def defer_compile_lock() -> None:
    """Install :func:`install_compile_lock` now if numba is loaded, else when it is (called
    on ``import demtool``: importing numba here would cost every command half a second)."""
    if "numba.core.dispatcher" in sys.modules:
        try:
            install_compile_lock()
        except Exception:  # noqa: BLE001 - an unknown numba: it compiles as before
            pass
    elif _NumbaFinder not in sys.meta_path:
        sys.meta_path.insert(0, _NumbaFinder)
