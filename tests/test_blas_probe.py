"""numba's BLAS probe sees a stand-in for scipy.linalg.cython_blas (demtool.blas):
kernels start without importing scipy.linalg, and BLAS still works where a kernel uses it.

Each check runs in a fresh interpreter: what numba imported stays imported."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import textwrap

from demtool import blas


def run_fresh(code: str) -> dict:
    result = subprocess.run([sys.executable, "-c", textwrap.dedent(code)],
                            capture_output=True, text=True, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_a_kernel_starts_without_scipy_linalg_and_numba_sees_a_blas():
    seen = run_fresh("""
        import json, sys
        import demtool, numba, numpy as np
        from numba.core import registry

        @numba.njit
        def total(a):
            return a.sum()

        value = float(total(np.arange(10.0)))
        import numba.np.arraymath as arraymath
        print(json.dumps({
            "value": value,
            "have_blas": arraymath._HAVE_BLAS,
            "linalg": "scipy.linalg" in sys.modules,
            "stand_in_left": "scipy.linalg.cython_blas" in sys.modules,
            "finder_left": any(type(f).__name__ == "_ProbeFinder" for f in sys.meta_path),
        }))
    """)
    assert seen == {"value": 45.0, "have_blas": True, "linalg": False,
                    "stand_in_left": False, "finder_left": False}


def test_a_kernel_calling_blas_gets_the_real_library():
    """np.dot of float64 matrices goes through scipy's cython_blas (dgemm)."""
    seen = run_fresh("""
        import json, sys
        import demtool, numba, numpy as np

        @numba.njit
        def product(a, b):
            return np.dot(a, b)

        a = np.arange(12.0).reshape(3, 4)
        b = np.arange(8.0).reshape(4, 2) - 3.0
        got = product(a, b)
        blas = sys.modules["scipy.linalg.cython_blas"]
        print(json.dumps({"equal": bool(np.array_equal(got, a @ b)),
                          "real": type(blas).__name__ == "module"}))
    """)
    assert seen == {"equal": True, "real": True}


def test_the_stand_in_answers_from_the_real_module_and_leaves_sys_modules():
    seen = run_fresh("""
        import json, sys
        from demtool.blas import DeferredModule

        stand_in = DeferredModule("json.tool")
        sys.modules["json.tool"] = stand_in
        main = stand_in.main
        import json.tool as real
        print(json.dumps({"same": main is real.main,
                          "replaced": sys.modules["json.tool"] is real,
                          "real_type": type(real).__name__}))
    """)
    assert seen == {"same": True, "replaced": True, "real_type": "module"}


def without_finder(monkeypatch):
    """This process's own finder (installed on ``import demtool``) set aside."""
    monkeypatch.setattr(sys, "meta_path", [f for f in sys.meta_path
                                           if not isinstance(f, blas._ProbeFinder)])


def test_nothing_is_deferred_once_numba_has_probed(monkeypatch):
    without_finder(monkeypatch)
    monkeypatch.setitem(sys.modules, blas.PROBING_MODULE, object())
    assert blas.defer_numba_probe() is False
    assert not any(isinstance(f, blas._ProbeFinder) for f in sys.meta_path)


def test_nothing_is_deferred_without_the_probed_module(monkeypatch):
    """Without scipy's cython_blas the probe must fail as numba expects (no BLAS)."""
    without_finder(monkeypatch)
    monkeypatch.delitem(sys.modules, blas.PROBING_MODULE, raising=False)
    monkeypatch.delitem(sys.modules, blas.PROBED_MODULE, raising=False)
    monkeypatch.setattr(blas, "PROBED_MODULE", "scipy.linalg.no_such_module")
    assert blas.defer_numba_probe() is False
    assert not any(isinstance(f, blas._ProbeFinder) for f in sys.meta_path)


def test_findable_walks_package_folders_without_importing_them():
    spec = importlib.util.find_spec("scipy")
    assert blas._findable("scipy.linalg.cython_blas", spec)
    assert not blas._findable("scipy.no_such_package.cython_blas", spec)
    assert not blas._findable("scipy.linalg.no_such_module", spec)
