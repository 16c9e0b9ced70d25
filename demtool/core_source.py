"""Defaults and constants of core modules, read from their source without importing them.

A stage's parameter module takes its defaults from the core function's signature
(:func:`demtool.parameters.core_defaults`, so each default is written once).  Importing
the core to read them loads numba and compiles nothing, but still costs half a second
and makes ``demtool <stage> --help`` depend on numba.  The functions here read the same
values from the core module's source with :mod:`ast` — literal defaults, and names of
module-level literal constants — and fall back to importing the module for anything
else, so the answer is always the one the import would give (a test compares both).

References are ``"module:name"`` strings: ``core_defaults("demtool.sgm.matcher:sgm")``.
"""

from __future__ import annotations

import ast
import copy
import functools
import importlib
import importlib.machinery
import importlib.util
import sys
from pathlib import Path
from typing import Any

from demtool.parameters import core_defaults as _imported_defaults


class _NotStatic(Exception):
    """A value that only the import can give."""


def _split(ref: str) -> tuple[str, str]:
    module, _, name = ref.partition(":")
    if not module or not name:
        raise ValueError(f"expected 'module:name', got {ref!r}")
    return module, name


def _find_spec(module: str) -> importlib.machinery.ModuleSpec | None:
    """``module``'s spec without importing its parent packages (``importlib.util.find_spec``
    imports them: ``demtool.maps``'s ``__init__`` loads every map module)."""
    parent, _, _ = module.rpartition(".")
    if not parent or parent in sys.modules:
        return importlib.util.find_spec(module)
    outer = _find_spec(parent)
    if outer is None or outer.submodule_search_locations is None:
        return None
    return importlib.machinery.PathFinder.find_spec(module, outer.submodule_search_locations)


def _source(module: str) -> Path:
    spec = _find_spec(module)
    if spec is None or spec.origin is None or not spec.origin.endswith(".py"):
        raise _NotStatic(module)
    return Path(spec.origin)


def _tree(module: str) -> ast.Module:
    return ast.parse(_source(module).read_text(encoding="utf-8"))


def _values(module: str) -> tuple[dict[str, Any], dict[str, ast.stmt]]:
    """The module's literal constants, and its top-level functions and classes by name
    (slimmed: a function's arguments, a class's decorators, bases and annotated fields),
    read once per version of the file."""
    path = _source(module)
    return _read_values(path, path.stat().st_mtime_ns)


@functools.lru_cache(maxsize=32)
def _read_values(path: Path, mtime_ns: int) -> tuple[dict[str, Any], dict[str, ast.stmt]]:
    """:func:`_values` of a source file.  The syntax tree itself is not kept: that of a
    500-line module is some 10^4 objects that every later garbage collection (the one at
    exit too) would walk."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    definitions: dict[str, ast.stmt] = {}
    for node in tree.body:
        name = getattr(node, "name", None)
        if name is None or name in definitions:
            continue  # not a definition, or a later one of a name (the first is read)
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            definitions[node.name] = ast.FunctionDef(name=node.name, args=node.args, body=[],
                                                     decorator_list=[])
        elif isinstance(node, ast.ClassDef):
            definitions[node.name] = ast.ClassDef(
                name=node.name, bases=node.bases, keywords=node.keywords,
                decorator_list=node.decorator_list,
                body=[item for item in node.body if isinstance(item, ast.AnnAssign)])
    return _constants(tree), definitions


def _constants(tree: ast.Module) -> dict[str, Any]:
    """Module-level ``NAME = <literal>`` (annotated or not)."""
    found: dict[str, Any] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target, value = node.targets[0], node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            target, value = node.target, node.value
        else:
            continue
        if isinstance(target, ast.Name):
            try:
                found[target.id] = ast.literal_eval(value)
            except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
                found.pop(target.id, None)
    return found


def _value(node: ast.expr, constants: dict[str, Any]) -> Any:
    if isinstance(node, ast.Name):
        if node.id in constants:
            return constants[node.id]
        raise _NotStatic(node.id)
    try:
        return ast.literal_eval(node)
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        raise _NotStatic(ast.dump(node)) from None


def _function_defaults(node: ast.FunctionDef | ast.AsyncFunctionDef,
                       constants: dict[str, Any]) -> dict[str, Any]:
    args = node.args
    positional = [*args.posonlyargs, *args.args]
    pairs = list(zip(positional[len(positional) - len(args.defaults):], args.defaults,
                     strict=True))
    pairs += [(a, d) for a, d in zip(args.kwonlyargs, args.kw_defaults, strict=True)
              if d is not None]
    return {arg.arg: _value(default, constants) for arg, default in pairs}


def _static_defaults(module: str, name: str) -> dict[str, Any]:
    constants, definitions = _values(module)
    node = definitions.get(name)
    if isinstance(node, ast.ClassDef):
        return _dataclass_defaults(node, constants)
    if isinstance(node, ast.FunctionDef):
        return _function_defaults(node, constants)
    raise _NotStatic(name)  # defined elsewhere


def _dataclass_defaults(node: ast.ClassDef, constants: dict[str, Any]) -> dict[str, Any]:
    """The defaults of a plain ``@dataclass``'s fields (``name: type = literal``, or
    ``field(default=literal)``), which are its ``__init__``'s.  A ``default_factory`` field
    is left out (its default is made per instance).  Anything else (a base class, another
    decorator, ``ClassVar``/``InitVar``, other ``field`` arguments alone) only the import
    can give."""
    def is_dataclass(decorator: ast.expr) -> bool:
        target = decorator.func if isinstance(decorator, ast.Call) else decorator
        return ast.unparse(target) in ("dataclass", "dataclasses.dataclass")

    if node.bases or node.keywords or len(node.decorator_list) != 1 or not is_dataclass(
            node.decorator_list[0]):
        raise _NotStatic(node.name)
    found = {}
    for item in node.body:
        if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
            if "ClassVar" in ast.unparse(item.annotation) or "InitVar" in ast.unparse(
                    item.annotation):
                raise _NotStatic(node.name)
            value = item.value
            if isinstance(value, ast.Call) and ast.unparse(value.func) in (
                    "field", "dataclasses.field") and not value.args:
                given = {k.arg: k.value for k in value.keywords}
                if "default" in given:
                    value = given["default"]
                elif "default_factory" in given:
                    continue  # made per instance: no value to read (nor to index)
                else:
                    raise _NotStatic(node.name)
            if value is not None:
                found[item.target.id] = _value(value, constants)
    return found


class _Defaults(dict):
    """Like :func:`demtool.parameters.core_defaults`: a missing name is a TypeError."""

    function = ""

    def __missing__(self, name: str) -> Any:
        raise TypeError(f"{self.function}() has no default for {name!r}")


def core_defaults(ref: str) -> dict[str, Any]:
    """The keyword defaults of the core function ``"module:name"``, by name.

    Read from the source when every default is a literal or a module-level literal
    constant; otherwise (and when the module is already imported) from the function's
    signature after importing it.

    Raises
    ------
    TypeError
        Indexing a keyword without a default (as :func:`demtool.parameters.core_defaults`).
    """
    module, name = _split(ref)
    if module not in sys.modules:
        try:
            found = _Defaults(_static_defaults(module, name))
            found.function = name
            return found
        except (_NotStatic, OSError, SyntaxError):
            pass
    return _imported_defaults(getattr(importlib.import_module(module), name))


def core_constant(ref: str) -> Any:
    """The value of the module-level constant ``"module:NAME"`` (a literal), import-free."""
    module, name = _split(ref)
    if module not in sys.modules:
        try:
            constants = _values(module)[0]
            if name in constants:
                return copy.deepcopy(constants[name])
        except (_NotStatic, OSError, SyntaxError):
            pass
    return getattr(importlib.import_module(module), name)
