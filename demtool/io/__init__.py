"""Every read and write of demtool's files: GeoTIFF rasters, images, NPZ and JSON.

Contracts (see DESIGN.md):

* Rasters are float32 GeoTIFF with nodata = NaN, written with rasterio.  A DEM's
  affine transform carries its pixel spacing in metres.  A raster in an image's own
  pixel frame has no CRS and the tag ``frame=image:<name>``.
* NPZ files carry ``format_version`` and ``kind``; each kind has a schema that
  :func:`read_npz` checks (keys, shapes, dtypes), naming the file and the key.
* Every write is atomic: the data go to a hidden temporary file beside the target,
  which is renamed into place.  Inside :func:`output_transaction` the renames are
  deferred until the whole stage has succeeded, so a failing or interrupted stage
  leaves no output at all; :func:`check_output_paths` refuses outputs over inputs and
  unwritable folders, and every filesystem error is one InputError line naming the
  path (see :mod:`demtool.outputs`).
* Every raster read applies the band's scale and offset (GDAL's, which include
  ISIS ``Base``/``Multiplier`` and PDS ``SCALING_FACTOR``/``OFFSET``) and its nodata
  (and an ISIS cube's special pixels), and returns float32 with NaN for nodata and
  for ±inf.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import InputError
from demtool.io.files import _first_line, require_file

# NPZ files with schemas (demtool.io.npz) are part of this module's interface too.
from demtool.io.npz import (  # noqa: F401
    NPZ_FORMAT_VERSION,
    NPZ_OPTIONAL_SCHEMAS,
    NPZ_SCHEMAS,
    read_npz,
    validate_npz,
    write_npz,
)
from demtool.io.quiet import ignoring

# Atomic writes, output transactions and output path checks live in demtool.outputs;
# they are part of this module's interface (io.output_transaction, io.atomic_path ...).
from demtool.outputs import (  # noqa: F401
    atomic_path,
    check_output_paths,
    output_transaction,
    resolve,
    write_error,
)

# --------------------------------------------------------------------------------------
# Rasters
# --------------------------------------------------------------------------------------


def decode_tag(tags: dict[str, str], key: str, default: Any = None) -> Any:
    """A raster tag written as JSON, decoded (the raw string when it is not JSON);
    ``default`` if absent."""
    if key not in tags:
        return default
    try:
        return json.loads(tags[key])
    except json.JSONDecodeError:
        return tags[key]


@dataclass(frozen=True)
class Raster:
    """A raster band read from disk.

    Attributes
    ----------
    data : (H, W) float32
        Values; NaN where the file has nodata.
    transform : affine.Affine
        Pixel-to-map transform (pixel spacing in metres for a DEM).
    crs : rasterio.crs.CRS or None
        None for rasters in an image's own pixel frame.
    tags : dict of str to str
        The dataset tags (provenance, frame, scene metadata).
    path : Path
        Where it was read from (for messages).
    """

    data: np.ndarray
    transform: Any
    crs: Any
    tags: dict[str, str] = field(default_factory=dict)
    path: Path | None = None

    @property
    def spacing(self) -> tuple[float, float]:
        """Pixel size (x, y) in transform units (metres for a DEM), both positive."""
        return abs(self.transform.a), abs(self.transform.e)

    def tag_json(self, key: str, default: Any = None) -> Any:
        """Decode a tag that was written as JSON (parameters, vectors); ``default`` if absent."""
        return decode_tag(self.tags, key, default)


def image_frame_transform(gsd_m: float = 1.0):
    """Transform of a raster in an image's own pixel frame with pixel spacing ``gsd_m``.

    Column ``c`` and row ``r`` map to x = c * gsd_m, y = -r * gsd_m (north-up style, so
    GDAL and QGIS show the raster the right way up).
    """
    from affine import Affine

    return Affine(float(gsd_m), 0.0, 0.0, 0.0, -float(gsd_m), 0.0)


def _open_dataset(path: Path, what: str):
    import rasterio
    from rasterio.errors import NotGeoreferencedWarning, RasterioIOError

    require_file(path, what)
    try:
        with ignoring(NotGeoreferencedWarning):
            return rasterio.open(path)
    except RasterioIOError as exc:
        raise InputError(f"{path}: cannot read {what}: {_first_line(exc)}") from None


def physical_values(data: np.ma.MaskedArray, scales, offsets) -> np.ndarray:
    """Stored values → the product's units, float32, NaN for nodata and for ±inf.

    ``value = stored * scale + offset`` per band (GDAL's band scale and offset: GeoTIFF
    ``scale_factor``/``add_offset`` metadata, ISIS3 ``Base``/``Multiplier``, PDS3
    ``SCALING_FACTOR``/``OFFSET``), computed in float64 and rounded once to float32.

    Parameters
    ----------
    data : (B, H, W) masked array, any dtype
        Stored values; masked where GDAL's mask band says nodata (the nodata value,
        an alpha band, an ISIS special pixel).
    scales, offsets : sequence of float, length B
        Per band; None or NaN mean 1 and 0.

    Returns
    -------
    (B, H, W) float32
        NaN where masked or not finite.
    """
    out = np.empty(data.shape, dtype=np.float32)
    mask = np.ma.getmaskarray(data)
    with np.errstate(over="ignore", invalid="ignore"):  # beyond float32: inf, then NaN
        for band, (scale, offset) in enumerate(zip(scales, offsets, strict=True)):
            scale = 1.0 if scale is None or not np.isfinite(scale) else float(scale)
            offset = 0.0 if offset is None or not np.isfinite(offset) else float(offset)
            stored = np.ma.getdata(data[band])
            if scale == 1.0 and offset == 0.0:
                out[band] = stored
            else:
                out[band] = stored.astype(np.float64) * scale + offset
    out[mask | ~np.isfinite(out)] = np.nan
    return out


def _read_bands(path: Path, what: str, bands: list[int] | None = None):
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    dataset = _open_dataset(path, what)
    with dataset:
        try:
            with ignoring(NotGeoreferencedWarning):
                indexes = bands or list(range(1, dataset.count + 1))
                data = dataset.read(indexes, masked=True)
        except (RasterioError, ValueError) as exc:
            raise InputError(f"{path}: cannot read {what}: {_first_line(exc)}") from None
        values = physical_values(data, [dataset.scales[i - 1] for i in indexes],
                                 [dataset.offsets[i - 1] for i in indexes])
        tags = dict(dataset.tags())
        transform = dataset.transform
        if dataset.crs is None and transform.is_identity:
            # No georeferencing (PNG, or GDAL dropped a unit transform): the image frame.
            transform = image_frame_transform(1.0)
        return values, transform, dataset.crs, tags, dataset.colorinterp


def read_raster(path: str | os.PathLike, *, band: int = 1, what: str = "raster",
                allow_all_nan: bool = False) -> Raster:
    """Read one band of a GeoTIFF (or any GDAL raster) as float32 with NaN nodata.

    The band's scale and offset are applied (heights in the units the product
    states, e.g. an int16 DEM in half-metres with scale 0.5 reads in metres); its
    nodata, mask band and ±inf become NaN (see :func:`physical_values`).

    Parameters
    ----------
    path : path-like
        The raster file.
    band : int
        1-based band index.
    what : str
        What the file is, for error messages ("DEM", "left image", ...).
    allow_all_nan : bool
        If False (default), a raster with no valid pixel is an InputError.

    Raises
    ------
    InputError
        Missing or unreadable file, missing band, or no valid pixel.
    """
    p = Path(path)
    dataset = _open_dataset(p, what)
    with dataset:
        count = dataset.count
    if not 1 <= band <= count:
        raise InputError(f"{p}: {what} has {count} band(s), band {band} requested")
    values, transform, crs, tags, _ = _read_bands(p, what, [band])
    data = values[0]
    if not allow_all_nan and not np.isfinite(data).any():
        raise InputError(f"{p}: {what} contains no valid (finite) pixel")
    return Raster(data=data, transform=transform, crs=crs, tags=tags, path=p)


def read_raster_pair(first: str | os.PathLike, second: str | os.PathLike, *,
                     what: tuple[str, str] = ("raster", "raster")) -> tuple[Raster, Raster]:
    """:func:`read_raster` of two files at once, in two threads (GDAL decodes with the
    GIL released: a 2048² deflate pair 0.14 -> 0.07 s); an error names the first file
    that fails, as two calls in turn would."""
    from concurrent.futures import ThreadPoolExecutor

    from rasterio.errors import NotGeoreferencedWarning

    # each read holds the filter (demtool.io.quiet: threads may hold it at once); held
    # here too, it stays in place from the first read to the last
    with ignoring(NotGeoreferencedWarning), ThreadPoolExecutor(max_workers=1) as pool:
        later = pool.submit(read_raster, second, what=what[1])
        return read_raster(first, what=what[0]), later.result()


def read_image(path: str | os.PathLike, *, what: str = "image") -> Raster:
    """Read any GDAL-readable image (GeoTIFF, PNG, JPEG, PDS3/PDS4, ISIS3) as grey float32.

    Colour images (3 or 4 bands) are converted to luminance with the ITU-R BT.601
    weights; an alpha band marks nodata.  Values are the stored DN times the band's
    scale plus its offset (both usually absent, so DN); nodata and ±inf are NaN.

    Returns
    -------
    Raster
        ``data`` is (H, W) float32 with NaN for nodata.
    """
    p = Path(path)
    values, transform, crs, tags, colorinterp = _read_bands(p, what)
    from rasterio.enums import ColorInterp

    if values.shape[0] >= 3:
        alpha = [i for i, c in enumerate(colorinterp) if c == ColorInterp.alpha]
        grey = 0.299 * values[0] + 0.587 * values[1] + 0.114 * values[2]
        if alpha:
            grey = np.where(values[alpha[0]] > 0, grey, np.nan)
        data = grey.astype(np.float32)
    else:
        data = values[0]
    if not np.isfinite(data).any():
        raise InputError(f"{p}: {what} contains no valid (finite) pixel")
    return Raster(data=data, transform=transform, crs=crs, tags=tags, path=p)


def _tag_value(value: Any) -> str:
    if isinstance(value, str):
        return value
    return json.dumps(value, default=_json_default, separators=(",", ":"))


def write_raster(path: str | os.PathLike, data: np.ndarray, *, transform=None, crs=None,
                 tags: Mapping[str, Any] | None = None,
                 band_names: list[str] | None = None, resampling: str | None = None) -> Path:
    """Write a float32 GeoTIFF with NaN nodata, atomically.

    Laid out by :func:`demtool.io.layout.raster_output`: tiled, with internal overviews
    above :data:`demtool.io.layout.OVERVIEW_MIN_SIDE` pixels, or a Cloud Optimized
    GeoTIFF under ``demtool --cog``.

    Parameters
    ----------
    path : path-like
        Output file.
    data : (H, W) or (B, H, W) array
        Values, cast to float32; NaN marks nodata.
    transform : affine.Affine, optional
        Pixel-to-map transform; default: the identity image frame
        (:func:`image_frame_transform` with 1 unit per pixel).
    crs : CRS or str, optional
        Coordinate reference system; None for image-frame rasters.
    tags : mapping, optional
        Dataset tags; non-string values are stored as JSON.  Use
        :meth:`demtool.provenance.Provenance.tags` for the provenance tags.
    band_names : list of str, optional
        Descriptions of the bands (masks, counts and classes by name get nearest-value
        overviews: :func:`demtool.io.layout.overview_resampling`).
    resampling : str, optional
        The overviews' resampling (``average``, ``nearest``), instead of the one the
        band names choose.
    """
    from demtool.io.layout import raster_output

    array = np.asarray(data, dtype=np.float32)
    if array.ndim == 2:
        array = array[np.newaxis]
    if array.ndim != 3:
        raise ValueError(f"write_raster expects a 2-D or 3-D array, got shape {data.shape}")
    count, height, width = array.shape
    profile = {
        "driver": "GTiff",
        "dtype": "float32",
        "nodata": float("nan"),
        "count": count,
        "height": height,
        "width": width,
        "transform": transform if transform is not None else image_frame_transform(1.0),
        "crs": crs,
        # DEFLATE (every GDAL build reads it) at level 1: half the time
        # of the default level 6 for 2 % more bytes (a 2048² disparity: 0.11 against
        # 0.24 s, 8.5 against 8.3 MB)
        "compress": "deflate",
        "zlevel": 1,
        "predictor": 3,
        "tiled": width >= 256 and height >= 256,
    }
    if profile["tiled"]:
        profile.update(blockxsize=256, blockysize=256)
    if width * height * count * 4 > 3.5e9:
        profile["BIGTIFF"] = "YES"
    with raster_output(path, profile, band_names=band_names, resampling=resampling,
                       tags={k: _tag_value(v) for k, v in (tags or {}).items()}) as dst:
        dst.write(array)
    return Path(path)


# --------------------------------------------------------------------------------------
# Windowed access (stages that stream images larger than memory: mapproject)
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RasterInfo:
    """A raster's size, georeferencing and tags, without its pixels.

    width, height, count : int; transform : affine.Affine; crs : CRS or None;
    tags : dict of str to str; path : Path.
    """

    width: int
    height: int
    count: int
    transform: Any
    crs: Any
    tags: dict[str, str]
    path: Path

    def tag_json(self, key: str, default: Any = None) -> Any:
        """Decode a tag written as JSON; ``default`` if absent."""
        return decode_tag(self.tags, key, default)


def raster_info(path: str | os.PathLike, *, what: str = "raster") -> RasterInfo:
    """Open a raster and return its :class:`RasterInfo` (InputError when unreadable)."""
    p = Path(path)
    with _open_dataset(p, what) as dataset:
        transform = dataset.transform
        if dataset.crs is None and transform.is_identity:
            transform = image_frame_transform(1.0)
        return RasterInfo(width=dataset.width, height=dataset.height, count=dataset.count,
                          transform=transform, crs=dataset.crs, tags=dict(dataset.tags()),
                          path=p)


def read_window(path: str | os.PathLike, window: tuple[int, int, int, int], *,
                band: int = 1, what: str = "raster") -> np.ndarray:
    """Read rows ``row0:row1`` and columns ``col0:col1`` of one band as float32, NaN nodata.

    The band's scale and offset are applied as in :func:`read_raster`.  The raster is
    opened for the window and closed: GDAL keeps the blocks an open dataset read in
    its block cache until it is closed (up to ``GDAL_CACHEMAX``), outside any memory
    budget of the caller.

    Parameters
    ----------
    path : path-like
    window : (row0, row1, col0, col1), pixels, within the raster
    band : int, 1-based
    what : str, for messages

    Returns
    -------
    (row1 − row0, col1 − col0) float32
    """
    return read_windows(path, [window], band=band, what=what)[0]


def read_windows(path: str | os.PathLike, windows: Sequence[tuple[int, int, int, int]], *,
                 band: int = 1, what: str = "raster") -> list[np.ndarray]:
    """:func:`read_window` of several windows of one band, the raster opened once.

    For many small windows scattered over a large raster (the cells round a few points):
    GDAL's block cache keeps the blocks the open dataset has read, so windows that share
    a block decompress it once; and no window spanning all of them is read.  Each
    window's values equal :func:`read_window`'s.

    Parameters
    ----------
    path : path-like
    windows : sequence of (row0, row1, col0, col1), pixels, each within the raster
    band : int, 1-based
    what : str, for messages

    Returns
    -------
    list of (row1 − row0, col1 − col0) float32, one per window
    """
    from rasterio.errors import NotGeoreferencedWarning, RasterioError
    from rasterio.windows import Window

    p = Path(path)
    out = []
    with _open_dataset(p, what) as dataset:
        scales, offsets = [dataset.scales[band - 1]], [dataset.offsets[band - 1]]
        for window in windows:
            r0, r1, c0, c1 = (int(v) for v in window)
            try:
                with ignoring(NotGeoreferencedWarning):
                    data = dataset.read([band], window=Window(c0, r0, c1 - c0, r1 - r0),
                                        masked=True)
            except (RasterioError, ValueError) as exc:
                raise InputError(f"{p}: cannot read {what}: {_first_line(exc)}") from None
            out.append(physical_values(data, scales, offsets)[0])
    return out


def read_decimated(path: str | os.PathLike, *, max_side: int = 256, band: int = 1,
                   what: str = "raster") -> np.ndarray:
    """One band read at most ``max_side`` cells a side (nearest cells of the whole raster,
    as a GDAL overview would give), float32, NaN nodata, scale and offset applied: a
    sample of a raster too large to read whole.
    """
    from rasterio.enums import Resampling
    from rasterio.errors import NotGeoreferencedWarning, RasterioError

    p = Path(path)
    with _open_dataset(p, what) as dataset:
        step = max(1, -(-max(dataset.height, dataset.width) // max_side))
        shape = (1, max(1, dataset.height // step), max(1, dataset.width // step))
        try:
            with ignoring(NotGeoreferencedWarning):
                data = dataset.read([band], out_shape=shape, masked=True,
                                    resampling=Resampling.nearest)
        except (RasterioError, ValueError) as exc:
            raise InputError(f"{p}: cannot read {what}: {_first_line(exc)}") from None
        return physical_values(data, [dataset.scales[band - 1]],
                               [dataset.offsets[band - 1]])[0]


class RasterBlockWriter:
    """A float32 GeoTIFF being written one window at a time (see :func:`raster_writer`)."""

    def __init__(self, dataset) -> None:
        self._dataset = dataset

    def write(self, data: np.ndarray, row0: int, col0: int) -> None:
        """Write a (h, w) or (B, h, w) block with its top-left cell at (row0, col0)."""
        from rasterio.windows import Window

        block = np.asarray(data, dtype=np.float32)
        if block.ndim == 2:
            block = block[np.newaxis]
        self._dataset.write(block, window=Window(int(col0), int(row0), block.shape[2],
                                                 block.shape[1]))


@contextlib.contextmanager
def raster_writer(path: str | os.PathLike, *, height: int, width: int, count: int = 1,
                  transform=None, crs=None, tags: Mapping[str, Any] | None = None,
                  band_names: list[str] | None = None, resampling: str | None = None):
    """Write a float32 GeoTIFF (NaN nodata, tiled, ZSTD) block by block, atomically.

    The file is created filled with NaN; the block yields a :class:`RasterBlockWriter`.
    Compression is ZSTD level 1 with the floating-point predictor (about 1.7x faster than
    :func:`write_raster`'s deflate level 1 at the same size on image data; GDAL >= 2.3
    reads it), since the rasters written this way are the large ones.  Overviews (or
    the COG layout) as :func:`write_raster`, built once every block is written.
    As :func:`write_raster`, the file appears (inside :func:`output_transaction`: at the
    end of the transaction) only when the block succeeds.
    """
    from demtool.io.layout import raster_output

    profile = {
        "driver": "GTiff", "dtype": "float32", "nodata": float("nan"), "count": count,
        "height": height, "width": width,
        "transform": transform if transform is not None else image_frame_transform(1.0),
        "crs": crs, "compress": "zstd", "zstd_level": 1, "predictor": 3, "tiled": True,
        "blockxsize": 256, "blockysize": 256,
    }
    if width * height * count * 4 > 3.5e9:
        profile["BIGTIFF"] = "YES"
    with raster_output(path, profile, band_names=band_names, resampling=resampling,
                       tags={k: _tag_value(v) for k, v in (tags or {}).items()}) as dst:
        yield RasterBlockWriter(dst)


# --------------------------------------------------------------------------------------
# JSON
# --------------------------------------------------------------------------------------


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (set, tuple)):
        return list(value)
    raise TypeError(f"cannot store {type(value).__name__} in JSON")


def _json_clean(value: Any) -> Any:
    """Replace non-finite floats by None so the file is strict JSON."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, np.floating):
        return _json_clean(float(value))
    if isinstance(value, Mapping):
        return {str(k): _json_clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_clean(value.tolist())
    return value


def dumps_json(obj: Any) -> str:
    """Serialise to strict, indented JSON (numpy values converted, NaN/inf become null)."""
    return json.dumps(_json_clean(obj), indent=2, default=_json_default, allow_nan=False)


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Write ``obj`` as indented JSON, atomically."""
    text = dumps_json(obj) + "\n"
    with atomic_path(path, suffix=".json") as temporary:
        temporary.write_text(text, encoding="utf-8")
    return Path(path)


def read_json(path: str | os.PathLike, what: str = "JSON file") -> Any:
    """Read a JSON file; InputError naming the file when missing or malformed."""
    p = require_file(path, what)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{p}: {what} is not valid JSON ({_first_line(exc)})") from None


def write_ply(path: str | os.PathLike, xyz: np.ndarray,
              properties: Mapping[str, np.ndarray] | None = None, *,
              comments: Sequence[str] = ()) -> Path:
    """Write a point cloud as binary little-endian PLY, atomically.

    Parameters
    ----------
    path : path-like
    xyz : (N, 3) float, metres: written as ``double x, y, z``
    properties : mapping name → (N,) float, optional, written as ``float`` per vertex
        (e.g. ``ray_gap``)
    comments : lines written as PLY ``comment`` s (frame, units, provenance)

    The format of Turk's PLY (Stanford, 1994) as read by CloudCompare, PDAL and ASP's
    ``point2dem`` tools; one ``vertex`` element.
    """
    points = np.asarray(xyz, dtype="<f8").reshape(-1, 3)
    extra = {name: np.asarray(values, dtype="<f4").ravel()
             for name, values in (properties or {}).items()}
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    fields += [(name, "<f4") for name in extra]
    record = np.empty(len(points), dtype=fields)
    record["x"], record["y"], record["z"] = points[:, 0], points[:, 1], points[:, 2]
    for name, values in extra.items():
        record[name] = values
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {line}" for line in comments]
    header.append(f"element vertex {len(points)}")
    header += ["property double x", "property double y", "property double z"]
    header += [f"property float {name}" for name in extra]
    header.append("end_header")
    with atomic_path(path, suffix=".ply") as temporary:
        with open(temporary, "wb") as handle:
            handle.write(("\n".join(header) + "\n").encode("ascii"))
            handle.write(record.tobytes())
    return Path(path)
