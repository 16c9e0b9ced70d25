"""BLAS at start-up: OpenBLAS's worker threads, and numba's BLAS probe.

**OpenBLAS's worker threads** (:func:`configure`, before numpy is imported).  numpy and
scipy each load their own OpenBLAS, and each starts a worker thread per core that spins
for 2^28 cycles (OpenBLAS's ``thread_timeout``, about 0.1 s) before it sleeps — once
when the library loads and again after every threaded BLAS call.  On a 2-core machine
that is 0.2 CPU s of every demtool command spent spinning, and a core taken from
demtool's own threads (SGM's two sweeps, numba's parallel loops) after a BLAS call.
``OPENBLAS_THREAD_TIMEOUT=4`` (OpenBLAS's smallest, 2^4 cycles) puts the workers to
sleep at once; BLAS stays multi-threaded, only waking its workers costs a few
microseconds more per call.

**numba's BLAS probe** (:func:`defer_numba_probe`).  When numba's CPU target starts
(the first compiled or cached kernel a process runs), it imports
``numba.np.arraymath``, whose module body asks whether a BLAS is there
(``_HAVE_BLAS = _check_blas()`` → ``numba.np.linalg.ensure_blas`` →
``import scipy.linalg.cython_blas``).  That import runs ``scipy.linalg``'s
``__init__``, which loads most of ``scipy.linalg`` and its array-API layer: 0.27 CPU s
and 0.2 s wall of every demtool command on this machine, commands that make no BLAS
call from numba and, like ``sgm``, import no ``scipy.linalg`` themselves.

:func:`defer_numba_probe` lets that one probe see a stand-in module: while
``numba.np.arraymath`` executes, ``sys.modules["scipy.linalg.cython_blas"]`` holds a
:class:`DeferredModule`, so the probe's ``import`` finds it (Python then imports only
the top package ``scipy``) and numba records that a BLAS is there — which is true: the
stand-in is installed only when ``scipy.linalg.cython_blas`` can be found.  It leaves
``sys.modules`` as soon as arraymath has run.  Any use of it meanwhile (another thread
reading an attribute, as numba's and Cython's loaders read ``__pyx_capi__``) imports
the real module and answers from it, so nothing sees a difference but the time.
Kernels that do call BLAS (``np.dot`` in a kernel) import the real module when numba
first compiles or loads them, as before.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import threading
import types

ENV = "OPENBLAS_THREAD_TIMEOUT"
SHORTEST = "4"  # OpenBLAS clamps the exponent to 4 … 30 cycles (2^n)


def configure() -> bool:
    """Set ``OPENBLAS_THREAD_TIMEOUT`` to its shortest unless the user set it.

    Called on ``import demtool`` (before numpy).  OpenBLAS reads the variable when it
    loads, so it has no effect where numpy was imported first (a user's own script).

    Returns
    -------
    bool
        True when the setting will take effect: numpy not imported yet and the
        variable not set by the user.
    """
    if ENV in os.environ or "numpy" in sys.modules:
        return False
    os.environ[ENV] = SHORTEST
    return True


#: the module whose body probes for a BLAS, and the module it imports to do so
PROBING_MODULE = "numba.np.arraymath"
PROBED_MODULE = "scipy.linalg.cython_blas"


class DeferredModule(types.ModuleType):
    """A stand-in in ``sys.modules`` that imports the real module on first use.

    Reading any attribute not set on it imports ``name`` (after taking the stand-in
    out of ``sys.modules``) and returns the real module's attribute.
    """

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self._lock = threading.Lock()

    def __getattr__(self, attribute: str):
        if attribute == "_lock":  # read before __init__ set it (a copy, an unpickling)
            raise AttributeError(attribute)
        with self._lock:
            if sys.modules.get(self.__name__) is self:
                del sys.modules[self.__name__]
            real = importlib.import_module(self.__name__)
        return getattr(real, attribute)


class _ProbeWrappingLoader(importlib.abc.Loader):
    """Runs the probing module with the stand-in in ``sys.modules``, then removes it."""

    def __init__(self, loader: importlib.abc.Loader) -> None:
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        stand_in = None
        if PROBED_MODULE not in sys.modules:
            stand_in = DeferredModule(PROBED_MODULE)
            sys.modules[PROBED_MODULE] = stand_in
        try:
            self.loader.exec_module(module)
        finally:
            if stand_in is not None and sys.modules.get(PROBED_MODULE) is stand_in:
                del sys.modules[PROBED_MODULE]

    def __getattr__(self, attribute: str):  # get_code, get_source, … of the real loader
        if attribute == "loader":
            raise AttributeError(attribute)
        return getattr(self.loader, attribute)


class _ProbeFinder(importlib.abc.MetaPathFinder):
    """Finds the probing module once, with its loader wrapped; then leaves
    ``sys.meta_path``."""

    def find_spec(self, name, path, target=None):
        if name != PROBING_MODULE:
            return None
        _remove_finder()
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is None or spec.loader is None:
            return spec
        spec.loader = _ProbeWrappingLoader(spec.loader)
        return spec


def _remove_finder() -> None:
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _ProbeFinder)]


def _findable(name: str, top_spec) -> bool:
    """Whether the submodule ``name`` of the package of ``top_spec`` can be found without
    importing any of its packages' ``__init__`` (only their folders are searched)."""
    spec = top_spec
    parts = name.split(".")
    for depth in range(1, len(parts)):
        locations = list(spec.submodule_search_locations or []) if spec else []
        if not locations:
            return False
        spec = importlib.machinery.PathFinder.find_spec(".".join(parts[:depth + 1]),
                                                        locations)
    return spec is not None


def defer_numba_probe() -> bool:
    """Defer numba's BLAS probe (see the module's text); called on ``import demtool``.

    Returns
    -------
    bool
        True when the probe will see the stand-in: numba's arraymath not imported yet,
        ``scipy.linalg.cython_blas`` neither imported nor missing (without scipy the
        probe must find no BLAS, and does), and no finder installed already.
    """
    if PROBING_MODULE in sys.modules or PROBED_MODULE in sys.modules:
        return False
    if any(isinstance(f, _ProbeFinder) for f in sys.meta_path):
        return True
    try:
        scipy_spec = importlib.util.find_spec("scipy")
    except (ImportError, ValueError):
        return False
    if not _findable(PROBED_MODULE, scipy_spec):
        return False
    sys.meta_path.insert(0, _ProbeFinder())
    return True
