"""Lazy package exports (PEP 562), so ``demtool STAGE --help`` and the parameter modules
load no numba, OpenCV or pycolmap.

A package ``__init__`` names its public objects by submodule and gets back the module
``__getattr__``, ``__dir__`` and ``__all__``; each name is imported on first use::

    __getattr__, __dir__, __all__ = lazy_exports(__name__, {
        "matcher": ("SGMResult", "sgm"),
        "strips": ("plan_strips",),
    })
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any


def lazy_exports(package: str, modules: Mapping[str, Sequence[str]]
                 ) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """Module ``__getattr__``/``__dir__``/``__all__`` of ``package`` for lazy imports.

    Parameters
    ----------
    package : str
        The package's ``__name__`` (it is in ``sys.modules`` while its ``__init__`` runs).
    modules : mapping of str to sequence of str
        Submodule name (relative to ``package``) → the names it exports.
    """
    exports = {name: f"{package}.{module}" for module, names in modules.items()
               for name in names}
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(exports[name]), name)
        namespace[name] = value  # later look-ups skip this function
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__, sorted(exports)
