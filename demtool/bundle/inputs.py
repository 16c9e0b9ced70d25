"""The images of a block: a selection.json, a list file, or paths as given.

Every way of naming a block's images ends as a :class:`Block`: view names (file
stems, unique) and paths.  Relative paths inside a file (a selection.json, a list
file) are relative to that file's folder, so a block can be adjusted from any
working folder.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from demtool.errors import InputError


@dataclass(frozen=True)
class Block:
    """Images of a bundle block.

    Attributes
    ----------
    names : tuple of str
        View names (file stems), unique, in input order.
    paths : tuple of Path
        Image files, same order.
    target : str or None
        The target view of a selection (None for a plain block).
    source : str
        Where the list came from (for messages): the selection or list file, or
        "arguments".
    """

    names: tuple[str, ...]
    paths: tuple[Path, ...]
    target: str | None
    source: str


def _resolve(path: str, folder: Path) -> Path:
    candidate = Path(path).expanduser()
    return candidate if candidate.is_absolute() else folder / candidate


def _check(names: Sequence[str], paths: Sequence[Path], source: str) -> None:
    seen: dict[str, Path] = {}
    for name, path in zip(names, paths, strict=True):
        if name in seen:
            raise InputError(f"{source}: two images share the view name '{name}' "
                             f"({seen[name]} and {path}); views are named by file stem")
        seen[name] = path
    if len(names) < 2:
        raise InputError(f"{source}: bundle adjustment needs at least 2 images, got "
                         f"{len(names)} ({', '.join(names) or 'none'})")
    for path in paths:
        if not path.is_file():
            raise InputError(f"{path}: image named in {source} not found")


def read_selection(path: str | os.PathLike) -> Block:
    """The selected images of a selection.json (from ``demtool select``), target first.

    Relative image paths are resolved against the selection file's folder (``select``
    writes them so); a path that is not there but exists relative to the working
    folder (selection files written before that) is accepted as is.
    """
    from demtool import io as dio

    selection_path = Path(path)
    content = dio.read_json(selection_path, "selection file")
    try:
        target = str(content["target"]["name"])
        entries = [(str(e["name"]), str(e["path"])) for e in content["selected"]]
        if target not in [name for name, _ in entries]:
            entries.insert(0, (target, str(content["target"]["path"])))
    except (KeyError, TypeError) as exc:
        raise InputError(f"{selection_path}: not a selection file from `demtool select` "
                         f"(missing {exc})") from None
    paths = []
    for _, text in entries:
        beside = _resolve(text, selection_path.parent)
        paths.append(beside if beside.is_file() or not Path(text).is_file() else Path(text))
    names = tuple(name for name, _ in entries)
    _check(names, paths, str(selection_path))
    return Block(names=names, paths=tuple(paths), target=target, source=str(selection_path))


def read_image_list(path: str | os.PathLike) -> Block:
    """A list file: one image path a line (relative to the list file's folder); blank
    lines and lines starting with ``#`` are skipped."""
    list_path = Path(path)
    if not list_path.is_file():
        raise InputError(f"{list_path}: image list not found")
    try:
        lines = list_path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{list_path}: cannot read the image list ({exc})") from None
    paths = []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        resolved = _resolve(text, list_path.parent)
        if not resolved.is_file():
            raise InputError(f"{list_path}: line {number}: image {text} not found "
                             f"(looked for {resolved})")
        paths.append(resolved)
    names = tuple(p.stem for p in paths)
    _check(names, paths, str(list_path))
    return Block(names=names, paths=tuple(paths), target=None, source=str(list_path))


def block_from_paths(paths: Sequence[str | os.PathLike]) -> Block:
    """A block of the image paths given on the command line (relative to the working
    folder)."""
    resolved = tuple(Path(p) for p in paths)
    names = tuple(p.stem for p in resolved)
    _check(names, resolved, "the command line")
    return Block(names=names, paths=resolved, target=None, source="the command line")
