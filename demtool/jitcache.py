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
