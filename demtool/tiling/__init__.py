"""Overlapping tiles shared by every tiled stage: the plan, the cache, the windowed writer.

A large raster is cut into tiles whose *cores* partition it; each tile is computed on
its *outer* window (the core plus margins wide enough that the result inside the core
does not depend on where the window ends: the stage's filter widths, its disparity
range, its path lengths), and only the core is kept ("crop to the core", the s2p and ASP
``stereo_corr`` choice; no blending, so every output pixel comes from exactly one tile
and a run is deterministic).  A stage describes its work as a :class:`TileJob`;
:func:`demtool.tiling.distributed.run_tiles` runs the jobs (in this process for one worker, on a
``dask.distributed`` cluster for more), each tile's core is cached in a work folder as it
finishes (:class:`TileCache`, keyed by the SHA-256 of the inputs and the parameters, so a
killed run resumes), and :func:`write_tiled_raster` assembles the cores window by window
into a tiled, deflate-compressed GeoTIFF inside the stage's output transaction.  Peak
memory is one tile per worker (plus one tile in the writing process), never the image.

This module imports neither Dask nor rasterio at import time.  The tiled stages' option
fields (:func:`~demtool.parameters.tile_size_field` and the others re-exported here) live
in :mod:`demtool.parameters`, so that the parameter modules do not import this one.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import shutil
import socket
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from demtool.errors import InputError, ParameterError
from demtool.parameters import (  # noqa: F401 - re-exported: fuse and mapproject params
    TILE_FIELDS,
    dry_run_field,
    scheduler_address_problem,
    scheduler_field,
    tile_overlap_field,
    tile_size_field,
)

BLOCK = 256  # GeoTIFF block side of every demtool raster (as demtool.io.write_raster)
#: GDAL creation options of a tiled run's outputs, by name: ``deflate`` is
#: :func:`demtool.io.write_raster`'s (level 1; GDAL's default level 6 costs ~2.4x the CPU
#: for a file ~2 % smaller on image data), ``zstd`` :func:`demtool.io.raster_writer`'s
COMPRESSIONS = {"deflate": {"compress": "deflate", "zlevel": 1, "predictor": 3},
                "zstd": {"compress": "zstd", "zstd_level": 1, "predictor": 3}}
CACHE_FORMAT = 1  # bump when the cache layout changes (old caches are then ignored)

# Parameters that change how tiles are run, never what they contain (not in cache keys).
EXECUTION_FIELDS = ("workers", "scheduler", "dry_run")


# ------------------------------------------------------------------------------ the plan
@dataclass(frozen=True)
class Tile:
    """One tile: its core (the pixels it outputs) and its outer window (what it reads).

    Bounds are half-open pixel ranges ``[row0, row1) × [col0, col1)`` of the full raster.
    """

    index: int
    core: tuple[int, int, int, int]   # row0, row1, col0, col1
    outer: tuple[int, int, int, int]  # row0, row1, col0, col1 (core + margins, clipped)

    @property
    def core_shape(self) -> tuple[int, int]:
        return self.core[1] - self.core[0], self.core[3] - self.core[2]

    @property
    def outer_shape(self) -> tuple[int, int]:
        return self.outer[1] - self.outer[0], self.outer[3] - self.outer[2]

    @property
    def crop(self) -> tuple[slice, slice]:
        """The core inside an array of the outer window."""
        r0, c0 = self.core[0] - self.outer[0], self.core[2] - self.outer[2]
        return slice(r0, r0 + self.core_shape[0]), slice(c0, c0 + self.core_shape[1])

    def describe(self) -> str:
        """``tile 3 (rows 0–1024, columns 2048–3072)``, for messages."""
        r0, r1, c0, c1 = self.core
        return f"tile {self.index} (rows {r0}–{r1}, columns {c0}–{c1})"


@dataclass(frozen=True)
class Tiling:
    """Tiles covering a ``height × width`` raster; their cores partition it."""

    height: int
    width: int
    tile_size: int
    margins: tuple[int, int, int, int]  # top, bottom, left, right
    tiles: tuple[Tile, ...]

    @property
    def largest_outer(self) -> tuple[int, int]:
        return (max(t.outer_shape[0] for t in self.tiles),
                max(t.outer_shape[1] for t in self.tiles))

    def describe(self) -> str:
        rows = len({t.core[0] for t in self.tiles})
        cols = len({t.core[2] for t in self.tiles})
        top, bottom, left, right = self.margins
        h, w = self.largest_outer
        return (f"{self.width}×{self.height} px in {len(self.tiles)} tiles ({cols}×{rows}) "
                f"of {self.tile_size} px, margins top {top} bottom {bottom} left {left} "
                f"right {right} px; largest tile read {w}×{h} px")


def plan_tiles(height: int, width: int, tile_size: int, *, overlap: int,
               extra_left: int = 0, extra_right: int = 0) -> Tiling:
    """Cut a raster into square tile cores with margins.

    Parameters
    ----------
    height, width : int
        Raster size, px.
    tile_size : int
        Side of the cores, px (the last row and column of tiles may be smaller).
    overlap : int
        Margin on every side of a core, px.
    extra_left, extra_right : int
        Further columns read on the left / right (a stereo stage's disparity range:
        with ``x_right = x_left − d``, a left core needs right-image columns down to
        ``col0 − d_max`` and up to ``col1 − d_min``).

    Returns
    -------
    Tiling
        Tiles in row-major order; outer windows clipped to the raster.

    Raises
    ------
    ParameterError
        A tile size below 16 px or a negative margin.
    """
    if tile_size < 16:
        raise ParameterError(f"--tile-size must be >= 16 px, got {tile_size}")
    if min(overlap, extra_left, extra_right) < 0:
        raise ParameterError(f"--tile-overlap must be >= 0, got {overlap}")
    margins = (overlap, overlap, overlap + extra_left, overlap + extra_right)
    tiles = []
    for r0 in range(0, height, tile_size):
        for c0 in range(0, width, tile_size):
            r1, c1 = min(r0 + tile_size, height), min(c0 + tile_size, width)
            outer = (max(0, r0 - margins[0]), min(height, r1 + margins[1]),
                     max(0, c0 - margins[2]), min(width, c1 + margins[3]))
            tiles.append(Tile(len(tiles), (r0, r1, c0, c1), outer))
    return Tiling(height, width, tile_size, margins, tuple(tiles))


def wants_tiles(height: int, width: int, params: Any, default_size: int = 1024) -> int:
    """The tile size a run uses (0 = today's untiled single-process path).

    A run is tiled when ``--tile-size`` is given, or when ``--scheduler`` / ``--dry-run``
    is (then ``default_size``), and the raster is larger than one tile.  ``--workers``
    alone never tiles: untiled, it is the thread count of the compiled kernels, as before;
    tiled, it is the number of tiles computed at a time (threads of this process,
    :mod:`demtool.tiling.local_threads`).  A raster that fits in one tile
    always takes the untiled path (no Dask import, no start-up cost), except a dry run.

    Raises
    ------
    ParameterError
        ``--tile-size`` between 1 and 15.
    """
    size = int(params.tile_size)
    if 0 < size < 16:
        raise ParameterError(f"--tile-size must be 0 (untiled) or >= 16 px, got {size}")
    if size == 0 and (params.scheduler or params.dry_run):
        size = default_size
    if size == 0:
        return 0
    if params.dry_run:  # a dry run plans even a one-tile image, and writes nothing
        return size
    return size if (height > size or width > size) else 0


# ----------------------------------------------------------------------------- the job
class TileJob(Protocol):
    """What a stage hands to the tile engine (a picklable, module-level class).

    Attributes
    ----------
    stage : str
        The stage's name (logging, the cache folder).
    bands : tuple of str
        Names of the float32 arrays one tile yields (e.g. disparity, confidence).
    """

    stage: str
    bands: tuple[str, ...]

    def compute(self, tile: Tile, threads: int) -> tuple[np.ndarray, dict[str, Any]]:
        """The tile's core: ``(len(bands), *tile.core_shape)`` float32, and a small info dict.

        Called within :func:`demtool.tiling.tasks.compute_tile`, which sets
        :func:`~demtool.tiling.tasks.usable_threads` and numba's thread count to
        ``threads`` for the call (0: the process's cores); a job does not set them again.
        """

    def memory_bytes(self, tile: Tile) -> int:
        """Estimated peak bytes of computing ``tile``."""


# --------------------------------------------------------------------------- the cache
def cache_key(inputs: Sequence[str | os.PathLike], parameters: Mapping[str, Any],
              tiling: Tiling, extra: Mapping[str, Any] | None = None) -> str:
    """SHA-256 over the inputs' contents, the parameters and the tiling (hex, 16 chars).

    Execution-only parameters (:data:`EXECUTION_FIELDS`) are left out, so a run resumed
    with another worker count or scheduler reuses the tiles.
    """
    from demtool import __version__
    from demtool.provenance import file_sha256

    material = {
        "format": CACHE_FORMAT,
        "version": __version__,
        "inputs": [file_sha256(p) for p in inputs],
        "parameters": {k: v for k, v in sorted(parameters.items())
                       if k not in EXECUTION_FIELDS},
        "tiling": [tiling.height, tiling.width, tiling.tile_size, list(tiling.margins)],
        "extra": dict(extra or {}),
    }
    text = json.dumps(material, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class TileCache:
    """A work folder holding each finished tile's core as ``tile_<index>.npy``.

    A file appears only complete (written beside, then renamed), and its info
    (``tile_<index>.json``) records its size and SHA-256, so a tile counts as done only
    when its file is the one written: a cached tile truncated or emptied since (a full
    disk, a copy cut short) is removed and recomputed, with a warning.

    With :meth:`hand_over` (a run that writes its outputs while its tiles run on threads
    of this process), the tiles stored here are also kept in memory, at most ``count`` of
    them (the lowest indices: the writer's next), until :meth:`release`: :meth:`load`
    returns the stored array instead of reading its file back.  The file is written as
    before (a killed run resumes from it); the values are the same.
    """

    #: info keys of the cache's own bookkeeping (not returned by :meth:`info`)
    _SIZE, _SHA = "_cache_bytes", "_cache_sha256"

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self._verified: dict[Path, tuple[int, int]] = {}
        self._kept: dict[int, np.ndarray] = {}
        self._keep = 0
        self._lock = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:
        # a copy in a worker process keeps nothing in memory (no one there loads it)
        return {"folder": self.folder, "_verified": dict(self._verified)}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["folder"])
        self._verified.update(state["_verified"])

    def hand_over(self, count: int) -> None:
        """Keep up to ``count`` stored tiles in memory for :meth:`load` (0: none)."""
        with self._lock:
            self._keep = max(0, int(count))
            self._trim()

    def _trim(self) -> None:
        """Drop kept tiles over the count, the highest indices first (the writer needs
        them last); the caller holds the lock."""
        while len(self._kept) > self._keep:
            del self._kept[max(self._kept)]

    def release(self, tile: Tile) -> None:
        """Forget the tile's array kept in memory (its file stays)."""
        with self._lock:
            self._kept.pop(tile.index, None)

    def path(self, tile: Tile) -> Path:
        return self.folder / f"tile_{tile.index:06d}.npy"

    def info_path(self, tile: Tile) -> Path:
        return self.folder / f"tile_{tile.index:06d}.json"

    def done(self, tile: Tile) -> bool:
        """True when the tile's file is there and is the one written (size, SHA-256)."""
        path = self.path(tile)
        try:
            stat = path.stat()
        except OSError:
            return False
        if self._verified.get(path) == (stat.st_size, stat.st_mtime_ns):
            return True
        problem = self._problem(tile, stat.st_size)
        if problem is None:
            self._verified[path] = (stat.st_size, stat.st_mtime_ns)
            return True
        from demtool.logs import get_logger

        get_logger(__name__).warning("%s: cached tile %s; recomputing it", path, problem)
        for stale in (path, self.info_path(tile)):
            with contextlib.suppress(OSError):
                stale.unlink()
        return False

    def _problem(self, tile: Tile, size: int) -> str | None:
        try:
            info = json.loads(self.info_path(tile).read_text())
        except (OSError, ValueError):
            info = {}
        if not isinstance(info, dict):
            info = {}
        if self._SIZE in info:
            if size != info[self._SIZE]:
                return f"has {size} bytes, {info[self._SIZE]} were written"
            digest = hashlib.sha256(self.path(tile).read_bytes()).hexdigest()
            return None if digest == info.get(self._SHA) else "differs from the one written"
        try:  # a cache written before checksums: readable and complete
            np.load(self.path(tile), mmap_mode="r", allow_pickle=False)
        except (OSError, ValueError, EOFError) as exc:
            return f"is unreadable ({exc})"
        return None

    def store(self, tile: Tile, values: np.ndarray, info: Mapping[str, Any]) -> None:
        """Save a tile's core ``(B, h, w)`` float32 and its info, atomically.

        The ``.npy`` file is ``np.save``'s bytes, written and hashed from the array itself
        (no copy of the tile in memory); a tile stored by this process counts as verified
        by :meth:`done` until its file changes (the writer does not hash it again)."""
        import io

        self.folder.mkdir(parents=True, exist_ok=True)
        array = np.ascontiguousarray(values, dtype=np.float32)
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(
            header, np.lib.format.header_data_from_array_1_0(array))
        head, body = header.getvalue(), memoryview(array.reshape(-1)).cast("B")
        digest = hashlib.sha256(head)
        digest.update(body)  # (hashlib releases the GIL: tiles on threads hash at once)
        size = len(head) + body.nbytes
        info = {**dict(info), self._SIZE: size, self._SHA: digest.hexdigest()}
        suffix = f".{os.getpid()}.{socket.gethostname()}.part"
        info_tmp = self.info_path(tile).with_name(self.info_path(tile).name + suffix)
        info_tmp.write_text(json.dumps(info, default=float))
        os.replace(info_tmp, self.info_path(tile))
        path = self.path(tile)
        tmp = path.with_name(path.name + suffix)
        with open(tmp, "wb") as handle:
            handle.write(head)
            handle.write(body)
        os.replace(tmp, path)
        stat = path.stat()
        if stat.st_size == size:
            self._verified[path] = (stat.st_size, stat.st_mtime_ns)
            with self._lock:
                if self._keep:
                    self._kept[tile.index] = array
                    self._trim()

    def load(self, tile: Tile) -> np.ndarray:
        """The tile's core ``(B, h, w)`` float32: the array kept in memory
        (:meth:`hand_over`), else its file's."""
        with self._lock:
            kept = self._kept.get(tile.index)
        if kept is not None:
            return kept
        return np.load(self.path(tile), allow_pickle=False)

    def info(self, tile: Tile) -> dict[str, Any]:
        try:
            info = json.loads(self.info_path(tile).read_text())
        except (OSError, ValueError):
            return {}
        if not isinstance(info, dict):
            return {}
        return {k: v for k, v in info.items() if k not in (self._SIZE, self._SHA)}

    def remove(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
        with contextlib.suppress(OSError):  # the parent work folder, when now empty
            self.folder.parent.rmdir()


def work_folder(out: str | os.PathLike) -> Path:
    """The default work folder of an output: ``.<name>.tiles`` beside it."""
    out = Path(out)
    return out.parent / f".{out.name}.tiles"


# ---------------------------------------------------------------------------- the lock
@contextlib.contextmanager
def output_lock(out: str | os.PathLike) -> Iterator[Path]:
    """Hold ``<out>.lock`` while a tiled run writes ``out``; refuse a second run.

    The lock file holds ``host pid``; a lock left by a process of this host that no
    longer runs (a killed run) is taken over.

    Raises
    ------
    InputError
        Another live run holds the lock.
    """
    lock = Path(out).with_name(Path(out).name + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    me = f"{socket.gethostname()} {os.getpid()}"
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = _read_lock(lock)
            if owner is not None and _stale(owner):
                with contextlib.suppress(OSError):
                    lock.unlink()
                continue
            raise InputError(f"{out}: another demtool run is writing this output (lock "
                             f"{lock} held by {owner or 'an unknown process'}); wait for it, "
                             "or delete the lock if that run is dead") from None
        with os.fdopen(fd, "w") as handle:
            handle.write(me)
        break
    else:  # pragma: no cover - a race with another run taking over the same stale lock
        raise InputError(f"{out}: could not take the lock {lock}")
    try:
        yield lock
    finally:
        with contextlib.suppress(OSError):
            if _read_lock(lock) == me:
                lock.unlink()


def _read_lock(lock: Path) -> str | None:
    try:
        return lock.read_text().strip() or None
    except OSError:
        return None


def _stale(owner: str) -> bool:
    host, _, pid = owner.partition(" ")
    if host != socket.gethostname() or not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    return False


# --------------------------------------------------------------------------- the I/O
def read_window(path: str | os.PathLike, window: tuple[int, int, int, int], *,
                what: str = "raster", band: int = 1) -> np.ndarray:
    """Read ``[row0, row1) × [col0, col1)`` of one band as float32, NaN nodata.

    The same values :func:`demtool.io.read_raster` gives for those pixels (scale and
    offset applied, nodata and ±inf as NaN), without reading the rest of the file.
    """
    from rasterio.errors import NotGeoreferencedWarning, RasterioError
    from rasterio.windows import Window

    from demtool import io as dio
    from demtool.io.quiet import ignoring

    r0, r1, c0, c1 = window
    dataset = dio._open_dataset(Path(path), what)
    with dataset, ignoring(NotGeoreferencedWarning):  # not catch_warnings: tiles' threads
        try:
            data = dataset.read([band], window=Window(c0, r0, c1 - c0, r1 - r0), masked=True)
        except (RasterioError, ValueError) as exc:
            raise InputError(f"{path}: cannot read {what}: {dio._first_line(exc)}") from None
        return dio.physical_values(data, [dataset.scales[band - 1]],
                                   [dataset.offsets[band - 1]])[0]


def raster_shape(path: str | os.PathLike, what: str = "raster") -> tuple[int, int]:
    """(height, width) of a raster, without reading its pixels."""
    from demtool import io as dio

    with dio._open_dataset(Path(path), what) as dataset:
        return dataset.height, dataset.width


def write_tiled_raster(path: str | os.PathLike, tiling: Tiling, cache: TileCache, *,
                       band: int | Sequence[int] = 0, transform=None, crs=None,
                       tags: Mapping[str, Any] | None = None,
                       band_name: str | Sequence[str] | None = None,
                       compress: str = "deflate") -> Path:
    """Assemble band ``band`` of the cached tile cores into a GeoTIFF, window by window.

    A sequence of bands (and of names) writes a multi-band file, in that order.

    The file has the profile of :func:`demtool.io.write_raster` (float32, NaN nodata,
    deflate level 1 with the floating-point predictor, 256 px blocks, overviews or the
    COG layout of :func:`demtool.io.layout.raster_output`), or with ``compress="zstd"``
    that of :func:`demtool.io.raster_writer` (ZSTD level 1, for a stage whose untiled
    path writes that way), and is written atomically,
    through :func:`demtool.outputs.atomic_path` (so inside an ``output_transaction`` it
    appears only when the whole transaction succeeds).  Tiles
    are written in index order, with no time stamp: the same cache gives the same bytes.
    Memory: one tile core at a time (plus GDAL's block cache).
    """
    with tiled_raster_output(path, tiling, band=band, transform=transform, crs=crs,
                             tags=tags, band_name=band_name, compress=compress) as writer:
        for tile in tiling.tiles:
            writer.write(tile, cache)
    return Path(path)


class TiledRasterWriter:
    """An open output of :func:`tiled_raster_output`: the bands of tile cores go in
    with :meth:`write`, in index order (see :func:`write_tiled_raster`)."""

    def __init__(self, dataset: Any, bands: list[int]) -> None:
        self.dataset, self.bands = dataset, bands

    def write(self, tile: Tile, cache: TileCache) -> None:
        from rasterio.windows import Window

        r0, r1, c0, c1 = tile.core
        self.dataset.write(cache.load(tile)[self.bands],
                           window=Window(c0, r0, c1 - c0, r1 - r0))


@contextlib.contextmanager
def tiled_raster_output(path: str | os.PathLike, tiling: Tiling, *,
                        band: int | Sequence[int] = 0, transform=None, crs=None,
                        tags: Mapping[str, Any] | None = None,
                        band_name: str | Sequence[str] | None = None,
                        compress: str = "deflate") -> Iterator[TiledRasterWriter]:
    """The output of :func:`write_tiled_raster`, open for tiles written one by one (the
    caller writes every tile, in index order, for the same bytes as that function's)."""
    if compress not in COMPRESSIONS:
        raise ValueError(f"unknown compression {compress!r}: should be one of "
                         + ", ".join(COMPRESSIONS))
    from demtool import io as dio
    from demtool.io.layout import raster_output

    bands = [band] if isinstance(band, int) else list(band)
    names = [band_name] if isinstance(band_name, str) else list(band_name or [])
    profile = {"driver": "GTiff", "dtype": "float32", "nodata": float("nan"),
               "count": len(bands),
               "height": tiling.height, "width": tiling.width,
               "transform": transform if transform is not None else dio.image_frame_transform(1.0),
               "crs": crs, **COMPRESSIONS[compress],
               "tiled": tiling.width >= BLOCK and tiling.height >= BLOCK}
    if profile["tiled"]:
        profile.update(blockxsize=BLOCK, blockysize=BLOCK)
    if tiling.width * tiling.height * 4 * len(bands) > 3.5e9:
        profile["BIGTIFF"] = "YES"
    with raster_output(path, profile, band_names=names,
                       tags={k: dio._tag_value(v) for k, v in (tags or {}).items()}) as dst:
        yield TiledRasterWriter(dst, bands)


def estimate_text(tiling: Tiling, memory_bytes: int, cores: int, tile_seconds: float,
                  cached: int) -> str:
    """The ``--dry-run`` report: the tiling, memory per worker, wall time on 1…64 nodes.

    The time is ``ceil(tiles / nodes) × t`` with ``t`` the calibration tile's time on
    this machine's ``cores`` cores (the largest tile, computed with every core): a node
    like this one computes one tile at a time with all its cores, or as many tiles as it
    has workers, each with its share of the cores, in about the same wall time.
    """
    remaining = len(tiling.tiles) - cached
    lines = [f"tiling: {tiling.describe()}",
             f"tiles cached from an earlier run: {cached}; to compute: {remaining}",
             f"estimated peak memory per worker: {memory_bytes / 2**20:.0f} MiB "
             "(one tile; the writing process holds one tile core at a time)",
             f"calibration tile (the largest): {tile_seconds:.2f} s on {cores} cores"]
    estimates = ", ".join(f"{n} node{'s' if n > 1 else ''} {_duration(remaining, n, tile_seconds)}"
                          for n in (1, 2, 4, 8, 16, 32, 64))
    lines.append(f"estimated wall time on nodes like this one: {estimates}")
    return "\n".join(lines)


def _duration(tiles: int, workers: int, seconds: float) -> str:
    total = math.ceil(tiles / workers) * seconds
    return f"{total / 60:.1f} min" if total >= 90 else f"{total:.0f} s"
