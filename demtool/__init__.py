"""demtool: Digital Elevation Models of planetary surfaces from spacecraft images."""

from demtool import blas, jitcache

blas.configure()  # before numpy loads OpenBLAS: its workers sleep instead of spinning
blas.defer_numba_probe()  # before numba starts: its BLAS probe skips scipy.linalg's import
jitcache.configure()  # before any demtool module imports numba: the compiled kernels' cache
jitcache.defer_compile_lock()  # concurrent processes compile a kernel once, not each

__all__ = ["__version__"]


def __getattr__(name: str) -> str:
    """``demtool.__version__``, read from the installed package's metadata on first use
    (PEP 562): importing importlib.metadata costs ~0.07 CPU s, which a command that does
    not record its version need not pay."""
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("demtool")
    except PackageNotFoundError:  # running from a source tree that is not installed
        value = "0.1.0"
    globals()["__version__"] = value
    return value
