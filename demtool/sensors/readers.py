"""One entry point for every camera file: :func:`read_sensor` dispatches on content.

=====================================  ==========================================
content                                model
=====================================  ==========================================
JSON with ``name_model`` (ALE ISD)     :class:`FrameSensor` / :class:`LineScanSensor` /
                                       :class:`PushFrameSensor`
ISIS3 cube (``Object = IsisCube``)     :class:`FrameSensor`, :class:`LineScanSensor`
                                       (:mod:`~demtool.sensors.isis_kinds`; SPICE attached)
ASP ``.tsai`` (``VERSION_n``/``PINHOLE``)  :class:`TsaiCamera` (body-fixed pinhole)
``.cahv(or|ore)`` text, PDS3 label    :class:`CahvoreCamera` (JPL CAHV/CAHVOR/CAHVORE)
RPC: GeoTIFF tags, NITF, DIMAP,       :class:`RpcSensor` (WGS84 heights;
``_RPC.TXT``, .RPB, OSSIM ``.geom``    :mod:`demtool.sensors.rpc_files`)
NPZ of kind ``cameras`` or ``bundle``  :class:`PinholeCamera` (one per image)
=====================================  ==========================================
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.sensors.base import SensorModel


def _sniff(path: Path) -> str:
    try:
        with open(path, "rb") as handle:
            head = handle.read(4096)
    except OSError as exc:
        raise InputError(f"{path}: cannot read sensor model ({exc.strerror or exc})") from None
    if head.startswith(b"PK"):
        return "npz"
    text = head.lstrip()
    if text.startswith(b"{"):
        return "isd"
    if b"IsisCube" in head[:200]:
        return "cube"
    if b"SFDU_LABEL" in head[:200] or (b"^QUBE" in head and b"Object = QUBE" in head):
        raise InputError(f"{path}: is an ISIS2 qube (PDS-style label with ^QUBE), not an "
                         "ISIS3 cube: it carries no SPICE tables; import it into ISIS3 "
                         "(lo2isis for Lunar Orbiter, pds2isis otherwise), run spiceinit, "
                         "and pass that cube or an ALE ISD")
    first = text.split(None, 1)[0].upper() if text.strip() else b""
    if first.startswith(b"VERSION_") or first == b"PINHOLE" or text.startswith(b"fu"):
        return "tsai"
    if text.startswith(b"PDS_VERSION_ID") and b"GEOMETRIC_CAMERA_MODEL" in head[:4096] \
            or path.suffix.lower() in (".cahv", ".cahvor", ".cahvore"):
        return "cahvor"
    if head[:4] in (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+") or b"LINE_NUM_COEFF" in head \
            or b"lineNumCoef" in head or text.startswith((b"LINE_OFF", b"satId", b"bandId")) \
            or b"line_num_coeff_" in head or b"polynomial_format" in head \
            or head.startswith((b"NITF", b"NSIF")) or path.suffix.lower() in (
                ".geom", ".rpb", ".ntf", ".nitf", ".jp2") \
            or path.name.upper().endswith("_RPC.TXT") \
            or path.name.upper().startswith(("DIM_", "RPC_")) and path.suffix.lower() == ".xml":
        return "rpc"
    raise InputError(f"{path}: not a sensor model demtool reads (ALE ISD JSON, ISIS3 cube "
                     "with SPICE, ASP .tsai, RPC in GeoTIFF/NITF/DIMAP/_RPC.TXT/.RPB/OSSIM "
                     ".geom, cameras.npz or bundle.npz)")


def read_sensors(path: str | Path, *, radii: tuple[float, float] | None = None,
                 require_surface: bool = True) -> dict[str, SensorModel]:
    """All sensor models of a file, by image name (one entry for an ISD, a cube or a
    ``.tsai``); ``radii`` (metres) is the body of a ``.tsai`` pinhole, which the file
    does not carry.  Every model is validated as it is read
    (:mod:`demtool.sensors.validate`: values, not only keys); ``require_surface=False``
    keeps a model that sees no surface of its body (with a note) instead of refusing it,
    for ``demtool camera``, which reports such a model."""
    from demtool.sensors import validate, validate_raw

    p = Path(path)
    kind = _sniff(p)
    check = {"require_surface": require_surface}
    if kind == "tsai":
        from demtool.sensors.tsai import read_tsai

        model = read_tsai(p, radii=radii)
        return {model.name: validate.check_model(model, p, "tsai", **check)}
    if kind == "cahvor":  # JPL's CAHV/CAHVOR/CAHVORE: checked by its reader
        from demtool.sensors.cahvor_files import read_cahvor, read_pds3_cahvor

        read = read_pds3_cahvor if p.suffix.lower() not in (".cahv", ".cahvor",
                                                            ".cahvore") else read_cahvor
        model = read(p, radii=radii)
        return {model.name: model}
    if kind == "isd":
        from demtool.sensors.isd import load_isd, sensor_from_isd
        from demtool.sensors.isd_forms import normalise_isd

        isd = validate_raw.check_isd(normalise_isd(load_isd(p), p), p)
        model = sensor_from_isd(isd, str(p))
        return {model.name or p.stem: validate.check_model(model, p, "isd", **check)}
    if kind == "cube":
        from demtool.sensors.isis_cube import read_isis_cube
        from demtool.sensors.isis_kinds import refuse_cube_kind

        refuse_cube_kind(p)  # map-projected, SAR, no SPICE: said before values are checked
        validate_raw.check_cube_label(p)
        with np.errstate(invalid="ignore", divide="ignore"):  # zero quaternions: checked next
            model = read_isis_cube(p)
        return {model.name: validate.check_model(model, p, "cube", **check)}
    if kind == "rpc":  # an RPC has no camera position or focal plane: its reader checks it
        from demtool.sensors.rpc_files import read_rpc

        model = read_rpc(p, radii=radii)
        return {model.name: model}
    return {name: validate.check_model(model, f"{p} ({name})", "npz", **check)
            for name, model in _read_npz(p).items()}


def read_sensor(path: str | Path, *, name: str | None = None,
                radii: tuple[float, float] | None = None,
                require_surface: bool = True) -> SensorModel:
    """Read one sensor model from any supported file (see the module docstring).

    Parameters
    ----------
    path : path-like
        ISD JSON, ISIS3 cube, ASP ``.tsai``, ``cameras.npz`` or ``bundle.npz``.
    name : str, optional
        Image name, required for an NPZ holding several cameras.
    radii : (float, float), optional
        Semi-axes of the body (metres) for a ``.tsai`` pinhole (used by its
        ``image_to_ground``); ignored for other files, which carry their own.
    require_surface : bool
        Refuse a camera that sees no surface of its body (default: the stages that need
        ground); False keeps it, with a note saying so.

    Raises
    ------
    InputError
        Unreadable or unrecognised file, bad content (one line naming the file and
        the key), or an NPZ with several cameras and no (or an unknown) ``name``.
    """
    models = read_sensors(path, radii=radii, require_surface=require_surface)
    if name is None:
        if len(models) == 1:
            return next(iter(models.values()))
        raise InputError(f"{path}: holds {len(models)} cameras ({', '.join(models)}); "
                         "say which image")
    if name not in models:
        raise InputError(f"{path}: has no camera named {name!r} (has {', '.join(models)})")
    return models[name]


def _read_npz(path: Path) -> dict[str, SensorModel]:
    from demtool import io
    from demtool.sensors.pinhole import cameras_from_arrays

    try:
        with np.load(path, allow_pickle=False) as npz:
            kind = str(npz["kind"]) if "kind" in npz.files else ""
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(f"{path}: not a readable NPZ file ({exc})") from None
    if kind not in ("cameras", "bundle"):
        raise InputError(f"{path}: is a {kind or 'non-demtool'} NPZ file, expected a cameras "
                         "or bundle file")
    arrays = io.read_npz(path, kind)
    try:
        return cameras_from_arrays(arrays)
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
