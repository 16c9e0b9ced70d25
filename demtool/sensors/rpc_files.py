"""RPC files: every source GDAL reads RPCs from, through rasterio, plus OSSIM ``.geom``.

=======================================  ===============================================
file                                     read by
=======================================  ===============================================
GeoTIFF with RPC tags, NITF with an      rasterio's ``dataset.rpcs`` (GDAL's ``RPC``
RPC00B/RPC00A TRE, DIMAP ``DIM_*.XML``,  metadata domain: GDAL puts RPC00A coefficients
any image GDAL opens                     in RPC00B order)
DigitalGlobe ``.RPB``, ``_RPC.TXT``      GDAL's sidecar readers (``GDALLoadRPBFile``,
                                         ``GDALLoadRPCFile``) through the image beside the
                                         file, or a 1 × 1 stand-in raster of the same name
Pléiades/SPOT ``RPC_*.XML``              the ``DIM_*.XML`` beside it (GDAL's DIMAP driver)
OSSIM keyword list ``.geom`` (OTB,       :func:`parse_geom` (OSSIM ``ossimRpcModel::
CARS, shareloc)                          loadState``: ``line_off: …``, ``line_num_coeff_00``
                                         … ``_19``, ``polynomial_format: A|B``)
=======================================  ===============================================

Image coordinates: GDAL's RPC metadata and OSSIM's keyword lists both put the first
pixel's centre at (0, 0) (shareloc reads the two alike).  A crop's offset into the
full image is honoured where the format records one: GDAL folds it into ``LINE_OFF`` /
``SAMP_OFF`` when it writes a crop (``gdal_translate -srcwin``), and an OSSIM keyword
list may carry ``sub_image_offset: x y`` (full-image pixels of the crop's first pixel),
subtracted here.

A file GDAL finds no RPC in, or a model that cannot be right (a truncated coefficient
list, a zero scale, a denominator that is all zeros or vanishes in the validity domain),
is refused in one line naming the file and the value.
"""

from __future__ import annotations

import re
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.rpc import COEFFS, SCALARS, WGS84, RpcSensor

__all__ = ["A_TO_B", "parse_geom", "read_rpc"]

#: RPC00B position of each RPC00A term (NITF STDI-0002 RPC00A/RPC00B; OSSIM
#: ``ossimRpcModel::polynomial``): A orders ``1 L P H LP LH PH LPH L² P² H² L³ L²P L²H
#: LP² P³ P²H LH² PH² H³``, B ``1 L P H LP LH PH L² P² H² PLH L³ LP² LH² L²P P³ PH² L²H
#: P²H H³``.
A_TO_B = (0, 1, 2, 3, 4, 5, 6, 10, 7, 8, 9, 11, 14, 17, 12, 15, 18, 13, 16, 19)
_TIFF = (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+")
_IMAGE_SUFFIXES = (".tif", ".tiff", ".ntf", ".nitf", ".jp2", ".img", ".vrt")
_SIDECAR = re.compile(r"(_RPC\.TXT|\.RPB)$", re.IGNORECASE)


def parse_geom(text: str, path: str | Path = "<geom>") -> tuple[dict, tuple[float, float]]:
    """The RPC of an OSSIM keyword list (``key: value`` lines; ``//`` comments).

    Keys, as ``ossimRpcModel::saveState`` writes them: ``polynomial_format`` (A or B;
    A is reordered to B, :data:`A_TO_B`), ``line_off``, ``samp_off``, ``lat_off``,
    ``long_off``, ``height_off``, the five ``*_scale``, and ``line_num_coeff_00`` …
    ``_19`` (likewise ``line_den``, ``samp_num``, ``samp_den``).  A common prefix
    (``image0.``, ``projection.``) is allowed.

    Returns
    -------
    rpc : dict
        :class:`~demtool.sensors.rpc.RpcSensor`'s ``rpc`` dict.
    offset : (line, sample)
        ``sub_image_offset`` (0, 0 when absent), full-image pixels.

    Raises
    ------
    InputError
        A key missing or not a number (named), a coefficient list short of 20.
    """
    path = Path(path)
    values: dict[str, str] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("//"):
            continue
        key, sep, value = line.partition(":")
        if not sep:
            raise InputError(f"{path}: line {number}: cannot parse {line!r} (an OSSIM keyword "
                             "list has 'key: value' lines)")
        values[key.strip().rsplit(".", 1)[-1]] = value.strip()  # any prefix ("image0.")

    def number(key: str) -> float:
        if key not in values:
            raise InputError(f"{path}: lacks the OSSIM RPC keyword '{key}'")
        try:
            return float(values[key].split()[0])
        except (ValueError, IndexError):
            raise InputError(f"{path}: '{key}' is not a number ({values[key]!r})") from None

    fmt = values.get("polynomial_format", "B").strip().upper()[:1]
    if fmt not in ("A", "B"):
        raise InputError(f"{path}: polynomial_format is {values['polynomial_format']!r}; "
                         "OSSIM knows A and B")
    rpc: dict = {key: number(key) for key in SCALARS}
    for key in COEFFS:
        found = [k for k in values if re.fullmatch(rf"{key}_\d+", k)]
        if len(found) != 20:
            present = sorted(int(k.rsplit("_", 1)[1]) for k in found)
            missing = next((i for i in range(20) if i not in present), len(present))
            raise InputError(f"{path}: '{key}' has {len(found)} coefficients, expected 20 "
                             f"({key}_{missing:02d} missing)")
        coeffs = np.array([number(f"{key}_{i:02d}") for i in range(20)])
        if fmt == "A":
            reordered = np.zeros(20)
            reordered[list(A_TO_B)] = coeffs
            coeffs = reordered
        rpc[key] = coeffs
    offset = (0.0, 0.0)
    if "sub_image_offset" in values:
        parts = values["sub_image_offset"].split()
        try:
            x, y = float(parts[0]), float(parts[1])
        except (ValueError, IndexError):
            raise InputError(f"{path}: sub_image_offset is {values['sub_image_offset']!r}, "
                             "expected 'x y' in pixels") from None
        offset = (y, x)
    return rpc, offset


def _rpc_dict(rpcs) -> dict:
    """rasterio's ``RPC`` as RpcSensor's dict."""
    return {k: getattr(rpcs, k) for k in list(SCALARS) + list(COEFFS)}


def _open_rpcs(image: Path):
    """(rpc dict or None, lines, samples, files GDAL read) of an image."""
    import rasterio

    with rasterio.Env(CPL_LOG="OFF"), warnings.catch_warnings():
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(image) as ds:
            rpcs = ds.rpcs
            return (None if rpcs is None else _rpc_dict(rpcs)), ds.height, ds.width, \
                [Path(f).name for f in ds.files]


def _sidecar_problem(text: str) -> str:
    """Why GDAL found no RPC in an ``.RPB`` / ``_RPC.TXT`` text: the first required key
    that is missing or has fewer than 20 coefficients (a message, not a model)."""
    upper = text.upper()
    for txt, rpb in SCALARS.values():
        if txt not in upper and rpb.upper() not in upper:
            return f"lacks the RPC key '{txt}'"
    for txt, rpb in COEFFS.values():
        numbered = len(re.findall(rf"\b{txt}_\d+\s*:", upper))
        listed = re.search(rf"\b{rpb.upper()}\s*=\s*\(([^)]*)\)", upper)
        count = numbered if numbered else (
            len([v for v in listed.group(1).split(",") if v.strip()]) if listed else 0)
        if count != 20:
            return f"'{txt}' has {count} coefficients, expected 20"
    return "GDAL reads no RPC from it (a value that is not a number?)"


def _read_sidecar(path: Path) -> tuple[dict, int, int, Path | None]:
    """An ``.RPB`` / ``_RPC.TXT`` read by GDAL: through the image beside it when there is
    one (then its size too), else through a 1 × 1 stand-in GeoTIFF of the same name."""
    import rasterio

    stem = _SIDECAR.sub("", path.name)
    for candidate in sorted(path.parent.glob(stem + ".*")):
        if candidate.suffix.lower() in _IMAGE_SUFFIXES:
            try:
                rpc, lines, samples, files = _open_rpcs(candidate)
            except rasterio.errors.RasterioIOError:
                continue
            if rpc is not None and path.name in files:
                return rpc, lines, samples, candidate
    with tempfile.TemporaryDirectory(prefix="demtool-rpc-") as tmp:
        stand_in = Path(tmp) / "image.tif"
        shutil.copyfile(path, Path(tmp) / ("image" + path.name[len(stem):]))
        with rasterio.Env(CPL_LOG="OFF"), warnings.catch_warnings():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(stand_in, "w", driver="GTiff", width=1, height=1, count=1,
                               dtype="uint8") as ds:
                ds.write(np.zeros((1, 1, 1), np.uint8))
        rpc, _, _, _ = _open_rpcs(stand_in)
    if rpc is None:
        try:
            text = path.read_text(encoding="utf-8", errors="replace")
        except OSError as exc:
            raise InputError(f"{path}: cannot read RPC file ({exc.strerror or exc})") from None
        raise InputError(f"{path}: {_sidecar_problem(text)}")
    return rpc, 0, 0, None


def _size_beside(path: Path) -> tuple[int, int]:
    """(lines, samples) of the image of the same name beside a model file, or (0, 0)."""
    import rasterio

    for candidate in sorted(path.parent.glob(path.stem + ".*")):
        if candidate.suffix.lower() in _IMAGE_SUFFIXES:
            try:
                with rasterio.Env(CPL_LOG="OFF"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
                    with rasterio.open(candidate) as ds:
                        return ds.height, ds.width
            except rasterio.errors.RasterioIOError:
                continue
    return 0, 0


def _dimap_beside(path: Path) -> Path:
    """The ``DIM_*.XML`` of a Pléiades/SPOT ``RPC_*.XML`` (same product suffix)."""
    suffix = path.name[4:]
    for candidate in (path.with_name("DIM_" + suffix), *sorted(path.parent.glob("DIM_*.XML")),
                      *sorted(path.parent.glob("DIM_*.xml"))):
        if candidate.exists():
            return candidate
    raise InputError(f"{path}: a DIMAP RPC file is read through its product's DIM_*.XML, "
                     "which is not beside it")


def read_rpc(path: str | Path, *, radii: tuple[float, float] | None = None
                  ) -> RpcSensor:
    """Read an RPC model (see the module docstring for the files).

    The image size is the image's own (GeoTIFF, NITF, DIMAP, the image of the same
    name beside a sidecar or ``.geom``); a lone ``.RPB``, ``_RPC.TXT`` or ``.geom`` gives
    0 × 0, said in the model's ``notes``.  ``radii`` (metres) replaces WGS 84 for another body.

    Raises
    ------
    InputError
        One line naming the file: unreadable, no RPC in it, a missing key or short
        coefficient list, a zero scale, a vanishing denominator.
    """
    import rasterio

    p = Path(path)
    notes: list[str] = []
    offset = (0.0, 0.0)
    try:
        with open(p, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        raise InputError(f"{p}: cannot read RPC model ({exc.strerror or exc})") from None
    text_head = head.decode("utf-8", errors="replace")
    lines = samples = 0
    if p.suffix.lower() == ".geom" or re.search(r"^\s*(\S+\.)?(polynomial_format|"
                                                r"line_num_coeff_\d\d)\s*:", text_head, re.M):
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            raise InputError(f"{p}: not a text OSSIM keyword list") from None
        rpc, offset = parse_geom(text, p)
        lines, samples = _size_beside(p)  # OTB writes img.geom beside img.tif
        if (lines, samples) == (0, 0):
            notes.append("an OSSIM keyword list gives no image size and no image lies "
                         "beside it")
    elif _SIDECAR.search(p.name) and head[:4] not in _TIFF:
        rpc, lines, samples, image = _read_sidecar(p)
        if image is None:
            notes.append("the RPC file gives no image size and no image lies beside it")
    else:
        source = _dimap_beside(p) if re.match(r"RPC_.*\.XML$", p.name, re.IGNORECASE) else p
        try:
            rpc, lines, samples, _ = _open_rpcs(source)
        except rasterio.errors.RasterioIOError as exc:
            raise InputError(f"{source}: GDAL cannot open it to read an RPC "
                             f"({str(exc).splitlines()[0]})") from None
        if rpc is None:
            raise InputError(f"{source}: not a sensor model: GDAL finds no RPC in it "
                             "(GeoTIFF tags, NITF RPC00B/RPC00A, DIMAP, .RPB or _RPC.TXT "
                             "beside it)")
    if offset != (0.0, 0.0):
        rpc = dict(rpc, line_off=float(rpc["line_off"]) - offset[0],
                   samp_off=float(rpc["samp_off"]) - offset[1])
    try:
        model = RpcSensor(rpc, lines=lines, samples=samples,
                          radii=WGS84 if radii is None else radii,
                          name=re.sub(r"_RPC$", "", p.stem, flags=re.IGNORECASE))
    except ValueError as exc:
        raise InputError(f"{p}: {exc}") from None
    model.notes = notes
    return model
