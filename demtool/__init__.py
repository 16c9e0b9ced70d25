"""demtool: Digital Elevation Models of planetary surfaces from spacecraft images."""

from importlib.metadata import PackageNotFoundError, version

from demtool import blas, jitcache

blas.configure()  # before numpy loads OpenBLAS: its workers sleep instead of spinning
blas.defer_numba_probe()  # before numba starts: its BLAS probe skips scipy.linalg's import
jitcache.configure()  # before any demtool module imports numba: the compiled kernels' cache
jitcache.defer_compile_lock()  # concurrent processes compile a kernel once, not each

try:
    __version__ = version("demtool")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.1.0"

__all__ = ["__version__"]
