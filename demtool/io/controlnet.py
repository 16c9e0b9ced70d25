"""ISIS control networks (``.net``): read the binary (protobuf) and PVL text forms, write
the binary form.

A binary network is a PVL label (``Object = ProtoBuffer``, ``Group = Core`` with the
byte offsets, ``Group = ControlNetworkInfo`` with ``Version``), then at
``HeaderStartByte`` a ``ControlNetFileHeaderV0002`` message and at ``PointsStartByte``
the points, one ``ControlPointFileEntryV0002`` each (:mod:`demtool.io.controlnet_messages`):

* version 2: the header lists every point's size (``pointMessageSizes``) and the points
  follow back to back;
* version 5 (what ISIS writes today): the header has no sizes; each point is preceded
  by its size as a 4-byte little-endian unsigned integer, until ``PointsBytes``.

The text form is ``Object = ControlNetwork`` with ``Version`` and one ``Object =
ControlPoint`` per point holding a ``Group = ControlMeasure`` per measure (versions 3 to
5 share the keywords read here).  Reference: ISIS ``ControlNetVersioner.cpp``
(``readProtobufV0002``, ``readProtobufV0005``, ``readPvlV0005``, ``toPvl``,
``writeProtobuf``) and plio's ``io_controlnetwork.py`` (``to_isis``, ``IsisStore``).

Pixel coordinates: ISIS counts samples and lines from 1 at the *centre* of the first
pixel; demtool (usgscsm's CSM convention, :mod:`demtool.sensors.base`) puts that centre
at 0.5.  So ``line = isis_line − 0.5`` and ``sample = isis_sample − 0.5`` on reading, and
the reverse on writing; residuals and sigmas (differences) are unchanged.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.io.controlnet_messages import (
    APRIORI_SOURCES,
    MEASURE_TYPES,
    POINT_TYPES,
    messages,
)

#: ISIS pixel coordinates minus demtool's (CSM): the first pixel's centre is 1.0 vs 0.5
ISIS_PIXEL_OFFSET = 0.5
#: where ISIS (and plio) put the protobuf header: after a 64 KiB PVL label
HEADER_START_BYTE = 65536
_OBSOLETE = {"obsolete_Tie": "Free", "obsolete_Ground": "Fixed", "Tie": "Free",
             "Ground": "Fixed"}


@dataclass
class ControlMeasure:
    """One measure of a control point: where one image sees it.

    ``line``/``sample`` (and ``apriori_line``/``apriori_sample``) are demtool's pixel
    coordinates (first pixel centre at 0.5); ``line_residual``/``sample_residual`` and
    the sigmas are pixels, as ISIS writes them.  ``log`` keeps ISIS's log entries as
    ``(doubleDataType, doubleDataValue, boolDataType, boolDataValue)`` tuples (None
    where absent).  Optional fields absent from the file are None.
    """

    serial: str
    type: str = "Candidate"
    line: float | None = None
    sample: float | None = None
    line_residual: float | None = None
    sample_residual: float | None = None
    chooser_name: str | None = None
    datetime: str | None = None
    edit_lock: bool | None = None
    ignore: bool | None = None
    jigsaw_rejected: bool | None = None
    diameter: float | None = None
    apriori_line: float | None = None
    apriori_sample: float | None = None
    line_sigma: float | None = None
    sample_sigma: float | None = None
    log: list = field(default_factory=list)

    @property
    def ignored(self) -> bool:
        return bool(self.ignore)


@dataclass
class ControlPoint:
    """One control point: its type, a priori and adjusted body-fixed position and
    covariance (metres, m²; (3,) and (3, 3) arrays or None), and its measures.

    ``type`` is ``"Free"`` (image to image: a tie point), ``"Constrained"`` (its a priori
    position weighted by ``apriori_covariance``) or ``"Fixed"`` (held at its a priori
    position); ISIS's obsolete ``Tie``/``Ground`` read as Free/Fixed.
    """

    id: str
    type: str = "Free"
    measures: list[ControlMeasure] = field(default_factory=list)
    chooser_name: str | None = None
    datetime: str | None = None
    edit_lock: bool | None = None
    ignore: bool | None = None
    jigsaw_rejected: bool | None = None
    reference_index: int | None = None
    apriori_surface_point_source: str | None = None
    apriori_surface_point_source_file: str | None = None
    apriori_radius_source: str | None = None
    apriori_radius_source_file: str | None = None
    latitude_constrained: bool | None = None
    longitude_constrained: bool | None = None
    radius_constrained: bool | None = None
    apriori_xyz: np.ndarray | None = None
    apriori_covariance: np.ndarray | None = None
    adjusted_xyz: np.ndarray | None = None
    adjusted_covariance: np.ndarray | None = None
    log: list = field(default_factory=list)

    @property
    def ignored(self) -> bool:
        return bool(self.ignore)


@dataclass
class ControlNetwork:
    """An ISIS control network: header fields and points (file order)."""

    network_id: str
    target_name: str
    points: list[ControlPoint]
    created: str | None = None
    last_modified: str | None = None
    description: str | None = None
    user_name: str | None = None
    version: int = 5

    @property
    def measure_count(self) -> int:
        return sum(len(p.measures) for p in self.points)

    def serials(self) -> list[str]:
        """The serial numbers measured, in order of first appearance."""
        seen: dict[str, None] = {}
        for point in self.points:
            for measure in point.measures:
                seen.setdefault(measure.serial, None)
        return list(seen)


# -- covariance: ISIS stores the upper triangle (xx, xy, xz, yy, yz, zz), m² ----------------


def _covariance(values, source: str, what: str) -> np.ndarray | None:
    values = [float(v) for v in values]
    if not values:
        return None
    if len(values) != 6:
        raise InputError(f"{source}: {what} has {len(values)} values; ISIS stores 6 "
                         "(xx, xy, xz, yy, yz, zz)")
    xx, xy, xz, yy, yz, zz = values
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _triangle(matrix) -> list[float]:
    m = np.asarray(matrix, dtype=np.float64)
    return [float(m[0, 0]), float(m[0, 1]), float(m[0, 2]), float(m[1, 1]), float(m[1, 2]),
            float(m[2, 2])]


def _shift(value, offset: float):
    return None if value is None else float(value) + offset


# -- binary form ---------------------------------------------------------------------------


def _optional(message, name: str):
    return getattr(message, name) if message.HasField(name) else None


def _log(entries) -> list:
    return [tuple(_optional(e, n) for n in ("doubleDataType", "doubleDataValue",
                                            "boolDataType", "boolDataValue"))
            for e in entries]


def _point_from_message(message, source: str) -> ControlPoint:
    names = {v: k for k, v in POINT_TYPES.items()}
    sources = {v: k for k, v in APRIORI_SOURCES.items()}
    measure_types = {v: k for k, v in MEASURE_TYPES.items()}
    kind = names[message.type]
    xyz = [_optional(message, f"apriori{a}") for a in "XYZ"]
    adjusted = [_optional(message, f"adjusted{a}") for a in "XYZ"]
    measures = []
    for m in message.measures:
        measures.append(ControlMeasure(
            serial=m.serialnumber, type=measure_types[m.type],
            line=_shift(_optional(m, "line"), -ISIS_PIXEL_OFFSET),
            sample=_shift(_optional(m, "sample"), -ISIS_PIXEL_OFFSET),
            line_residual=_optional(m, "lineResidual"),
            sample_residual=_optional(m, "sampleResidual"),
            chooser_name=_optional(m, "choosername"), datetime=_optional(m, "datetime"),
            edit_lock=_optional(m, "editLock"), ignore=_optional(m, "ignore"),
            jigsaw_rejected=_optional(m, "jigsawRejected"),
            diameter=_optional(m, "diameter"),
            apriori_line=_shift(_optional(m, "aprioriline"), -ISIS_PIXEL_OFFSET),
            apriori_sample=_shift(_optional(m, "apriorisample"), -ISIS_PIXEL_OFFSET),
            line_sigma=_optional(m, "linesigma"), sample_sigma=_optional(m, "samplesigma"),
            log=_log(m.log)))
    return ControlPoint(
        id=message.id, type=_OBSOLETE.get(kind, kind), measures=measures,
        chooser_name=_optional(message, "chooserName"),
        datetime=_optional(message, "datetime"), edit_lock=_optional(message, "editLock"),
        ignore=_optional(message, "ignore"),
        jigsaw_rejected=_optional(message, "jigsawRejected"),
        reference_index=_optional(message, "referenceIndex"),
        apriori_surface_point_source=sources.get(_optional(message, "aprioriSurfPointSource")),
        apriori_surface_point_source_file=_optional(message, "aprioriSurfPointSourceFile"),
        apriori_radius_source=sources.get(_optional(message, "aprioriRadiusSource")),
        apriori_radius_source_file=_optional(message, "aprioriRadiusSourceFile"),
        latitude_constrained=_optional(message, "latitudeConstrained"),
        longitude_constrained=_optional(message, "longitudeConstrained"),
        radius_constrained=_optional(message, "radiusConstrained"),
        apriori_xyz=None if None in xyz else np.array(xyz, dtype=np.float64),
        apriori_covariance=_covariance(message.aprioriCovar, source,
                                       f"point {message.id}: aprioriCovar"),
        adjusted_xyz=None if None in adjusted else np.array(adjusted, dtype=np.float64),
        adjusted_covariance=_covariance(message.adjustedCovar, source,
                                        f"point {message.id}: adjustedCovar"),
        log=_log(message.log))


def _set(message, name: str, value) -> None:
    if value is not None:
        setattr(message, name, value)


def _set_log(entries, log) -> None:
    for values in log:
        entry = entries.add()
        for name, value in zip(("doubleDataType", "doubleDataValue", "boolDataType",
                                "boolDataValue"), values, strict=True):
            _set(entry, name, value)


def _point_message(point: ControlPoint):
    message = messages().point()
    message.id = point.id
    message.type = POINT_TYPES[point.type]
    _set(message, "chooserName", point.chooser_name)
    _set(message, "datetime", point.datetime)
    _set(message, "editLock", point.edit_lock)
    _set(message, "ignore", point.ignore)
    _set(message, "jigsawRejected", point.jigsaw_rejected)
    _set(message, "referenceIndex", point.reference_index)
    for name, value in (("aprioriSurfPointSource", point.apriori_surface_point_source),
                        ("aprioriRadiusSource", point.apriori_radius_source)):
        _set(message, name, None if value is None else APRIORI_SOURCES[value])
    _set(message, "aprioriSurfPointSourceFile", point.apriori_surface_point_source_file)
    _set(message, "aprioriRadiusSourceFile", point.apriori_radius_source_file)
    _set(message, "latitudeConstrained", point.latitude_constrained)
    _set(message, "longitudeConstrained", point.longitude_constrained)
    _set(message, "radiusConstrained", point.radius_constrained)
    for prefix, xyz in (("apriori", point.apriori_xyz), ("adjusted", point.adjusted_xyz)):
        if xyz is not None:
            for axis, value in zip("XYZ", xyz, strict=True):
                setattr(message, f"{prefix}{axis}", float(value))
    if point.apriori_covariance is not None:
        message.aprioriCovar.extend(_triangle(point.apriori_covariance))
    if point.adjusted_covariance is not None:
        message.adjustedCovar.extend(_triangle(point.adjusted_covariance))
    _set_log(message.log, point.log)
    for m in point.measures:
        out = message.measures.add()
        out.serialnumber = m.serial
        out.type = MEASURE_TYPES[m.type]
        _set(out, "sample", _shift(m.sample, ISIS_PIXEL_OFFSET))
        _set(out, "line", _shift(m.line, ISIS_PIXEL_OFFSET))
        _set(out, "sampleResidual", m.sample_residual)
        _set(out, "lineResidual", m.line_residual)
        _set(out, "choosername", m.chooser_name)
        _set(out, "datetime", m.datetime)
        _set(out, "editLock", m.edit_lock)
        _set(out, "ignore", m.ignore)
        _set(out, "jigsawRejected", m.jigsaw_rejected)
        _set(out, "diameter", m.diameter)
        _set(out, "apriorisample", _shift(m.apriori_sample, ISIS_PIXEL_OFFSET))
        _set(out, "aprioriline", _shift(m.apriori_line, ISIS_PIXEL_OFFSET))
        _set(out, "samplesigma", m.sample_sigma)
        _set(out, "linesigma", m.line_sigma)
        _set_log(out.log, m.log)
    return message


def _label_end(data: bytes) -> int:
    for marker in (b"\nEnd\n", b"\nEnd\r\n", b"\nEND\n", b"\nEnd"):
        end = data.find(marker)
        if end >= 0:
            return end + len(marker)
    return min(len(data), HEADER_START_BYTE)


def _parse_pvl(text: str, source: Path):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImportWarning)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import pvl

        try:
            return pvl.loads(text)
        except Exception as exc:  # pvl raises several parser errors
            raise InputError(f"{source}: not an ISIS control network (cannot parse its "
                             f"PVL: {str(exc).splitlines()[0]})") from None


def _int(group, key: str, source: Path, what: str) -> int:
    try:
        return int(group[key])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{source}: {what} has no integer {key}") from None


def _read_binary(data: bytes, label, source: Path) -> ControlNetwork:
    from google.protobuf.message import DecodeError

    proto = label["ProtoBuffer"]
    core = proto.get("Core")
    info = proto.get("ControlNetworkInfo", {})
    if core is None:
        raise InputError(f"{source}: the ProtoBuffer label has no Core group")
    version = int(info.get("Version", 1))
    if version not in (2, 5):
        raise InputError(f"{source}: protobuf control network version {version} is not "
                         "supported (ISIS writes 5; 2 is read too); convert it with ISIS "
                         "cnetbin2pvl / cnetpvl2bin")
    start = _int(core, "HeaderStartByte", source, "Core")
    length = _int(core, "HeaderBytes", source, "Core")
    points_start = _int(core, "PointsStartByte", source, "Core") if "PointsStartByte" in \
        core else start + length
    points_bytes = _int(core, "PointsBytes", source, "Core") if "PointsBytes" in core \
        else len(data) - points_start
    if start + length > len(data) or points_start + points_bytes > len(data):
        raise InputError(f"{source}: truncated: the label gives {points_start + points_bytes}"
                         f" bytes, the file has {len(data)}")
    msgs = messages()
    header = msgs.header()
    try:
        header.ParseFromString(data[start:start + length])
    except DecodeError as exc:
        raise InputError(f"{source}: cannot decode the protobuf header ({exc})") from None
    points = []
    position, end = points_start, points_start + points_bytes
    sizes = list(header.pointMessageSizes) if version == 2 else None
    while (position < end) if sizes is None else (len(points) < len(sizes)):
        if sizes is None:
            if position + 4 > end:
                raise InputError(f"{source}: truncated point size at byte {position}")
            size = struct.unpack("<I", data[position:position + 4])[0]
            position += 4
        else:
            size = sizes[len(points)]
        if position + size > end:
            raise InputError(f"{source}: point {len(points)} runs past PointsBytes")
        message = msgs.point()
        try:
            message.ParseFromString(data[position:position + size])
        except DecodeError as exc:
            raise InputError(f"{source}: cannot decode control point {len(points)} "
                             f"({exc})") from None
        points.append(_point_from_message(message, str(source)))
        position += size
    return ControlNetwork(
        network_id=header.networkId, target_name=header.targetName, points=points,
        created=_optional(header, "created"), last_modified=_optional(header, "lastModified"),
        description=_optional(header, "description"), user_name=_optional(header, "userName"),
        version=version)


# -- text form -----------------------------------------------------------------------------


def _value(group, key: str):
    value = group.get(key)
    if value is None:
        return None
    if hasattr(value, "value"):  # pvl Quantity with units
        value = value.value
    return value


def _number(group, key: str, offset: float = 0.0):
    value = _value(group, key)
    return None if value is None else float(value) + offset


def _flag(group, key: str):
    value = _value(group, key)
    if value is None:
        return None
    return value if isinstance(value, bool) else str(value).strip().lower() in ("true", "yes")


def _text(group, key: str):
    value = _value(group, key)
    return None if value is None else str(value)


def _read_pvl(label, source: Path) -> ControlNetwork:
    network = label["ControlNetwork"]
    version = int(network.get("Version", 1))
    if version < 3:
        raise InputError(f"{source}: PVL control network version {version} is not supported "
                         "(3 to 5 are); convert it with ISIS cnetbin2pvl")
    points = []
    for key, value in network.items():
        if key != "ControlPoint":
            continue
        pid = _text(value, "PointId")
        if pid is None:
            raise InputError(f"{source}: control point {len(points)} has no PointId")
        kind = _text(value, "PointType") or "Free"
        kind = _OBSOLETE.get(kind, kind)
        if kind not in ("Free", "Constrained", "Fixed"):
            raise InputError(f"{source}: point {pid}: unknown PointType {kind!r}")
        measures = []
        for mkey, group in value.items():
            if mkey != "ControlMeasure":
                continue
            serial = _text(group, "SerialNumber")
            if serial is None:
                raise InputError(f"{source}: point {pid}: a measure has no SerialNumber")
            log = []
            for name, number in (("GoodnessOfFit", 2), ("MinimumPixelZScore", 3),
                                 ("MaximumPixelZScore", 4), ("PixelShift", 5),
                                 ("WholePixelCorrelation", 6), ("SubPixelCorrelation", 7)):
                if _value(group, name) is not None:
                    log.append((number, _number(group, name), None, None))
            measures.append(ControlMeasure(
                serial=serial, type=_text(group, "MeasureType") or "Candidate",
                line=_number(group, "Line", -ISIS_PIXEL_OFFSET),
                sample=_number(group, "Sample", -ISIS_PIXEL_OFFSET),
                line_residual=_number(group, "LineResidual"),
                sample_residual=_number(group, "SampleResidual"),
                chooser_name=_text(group, "ChooserName"), datetime=_text(group, "DateTime"),
                edit_lock=_flag(group, "EditLock"), ignore=_flag(group, "Ignore"),
                jigsaw_rejected=_flag(group, "JigsawRejected"),
                diameter=_number(group, "Diameter"),
                apriori_line=_number(group, "AprioriLine", -ISIS_PIXEL_OFFSET),
                apriori_sample=_number(group, "AprioriSample", -ISIS_PIXEL_OFFSET),
                line_sigma=_number(group, "LineSigma"),
                sample_sigma=_number(group, "SampleSigma"), log=log))
        xyz = [_number(value, f"Apriori{a}") for a in "XYZ"]
        adjusted = [_number(value, f"Adjusted{a}") for a in "XYZ"]
        points.append(ControlPoint(
            id=pid, type=kind, measures=measures,
            chooser_name=_text(value, "ChooserName"), datetime=_text(value, "DateTime"),
            edit_lock=_flag(value, "EditLock"), ignore=_flag(value, "Ignore"),
            jigsaw_rejected=_flag(value, "JigsawRejected"),
            apriori_surface_point_source=_text(value, "AprioriXYZSource"),
            apriori_surface_point_source_file=_text(value, "AprioriXYZSourceFile"),
            apriori_radius_source=_text(value, "AprioriRadiusSource"),
            apriori_radius_source_file=_text(value, "AprioriRadiusSourceFile"),
            latitude_constrained=_flag(value, "LatitudeConstrained"),
            longitude_constrained=_flag(value, "LongitudeConstrained"),
            radius_constrained=_flag(value, "RadiusConstrained"),
            apriori_xyz=None if None in xyz else np.array(xyz),
            apriori_covariance=_covariance(value.get("AprioriCovarianceMatrix") or [],
                                           str(source), f"point {pid}: "
                                           "AprioriCovarianceMatrix"),
            adjusted_xyz=None if None in adjusted else np.array(adjusted),
            adjusted_covariance=_covariance(value.get("AdjustedCovarianceMatrix") or [],
                                            str(source), f"point {pid}: "
                                            "AdjustedCovarianceMatrix")))
        reference = [i for i, (mkey, group) in enumerate(
            (k, g) for k, g in value.items() if k == "ControlMeasure")
            if _flag(group, "Reference")]
        if reference:
            points[-1].reference_index = reference[0]
    return ControlNetwork(
        network_id=_text(network, "NetworkId") or "", target_name=_text(network,
                                                                         "TargetName") or "",
        points=points, created=_text(network, "Created"),
        last_modified=_text(network, "LastModified"),
        description=_text(network, "Description"), user_name=_text(network, "UserName"),
        version=version)


def read_control_network(path: str | os.PathLike) -> ControlNetwork:
    """Read an ISIS control network, binary (protobuf version 2 or 5) or PVL text
    (versions 3 to 5); see the module docstring.

    Raises
    ------
    InputError
        Not a control network, an unsupported version, or a truncated/undecodable file.
    """
    from demtool.io.files import require_file

    source = require_file(path, "control network")
    try:
        data = source.read_bytes()
    except OSError as exc:
        raise InputError(f"{source}: cannot read control network "
                         f"({exc.strerror or exc})") from None
    head = data[:256].lstrip()
    if head.startswith(b"Object = ProtoBuffer") or head.startswith(b"Object=ProtoBuffer"):
        label = _parse_pvl(data[:_label_end(data)].decode("latin-1"), source)
        return _read_binary(data, label, source)
    if b"ControlNetwork" in data[:4096]:
        label = _parse_pvl(data.decode("latin-1"), source)
        if "ControlNetwork" in label:
            return _read_pvl(label, source)
    raise InputError(f"{source}: not an ISIS control network (no 'Object = ProtoBuffer' "
                     "or 'Object = ControlNetwork' label)")


def _pvl_label(network: ControlNetwork, *, version: int, header_bytes: int,
               points_start: int, points_bytes: int, measures: int) -> str:
    def text(value) -> str:
        value = "" if value is None else str(value)
        return f'"{value}"' if (not value or any(c in value for c in ' ="\'#;')) else value

    lines = ["Object = ProtoBuffer", "  Object = Core",
             f"    HeaderStartByte = {HEADER_START_BYTE}",
             f"    HeaderBytes     = {header_bytes}",
             f"    PointsStartByte = {points_start}",
             f"    PointsBytes     = {points_bytes}", "  End_Object", "",
             "  # This group is for informational purposes only",
             "  Group = ControlNetworkInfo",
             f"    NetworkId        = {text(network.network_id)}",
             f"    TargetName       = {text(network.target_name)}",
             f"    UserName         = {text(network.user_name)}",
             f"    Created          = {text(network.created)}",
             f"    LastModified     = {text(network.last_modified)}",
             f"    Description      = {text(network.description)}",
             f"    NumberOfPoints   = {len(network.points)}",
             f"    NumberOfMeasures = {measures}",
             f"    Version          = {version}", "  End_Group", "End_Object", "End", ""]
    return "\n".join(lines)


def control_network_bytes(network: ControlNetwork, *, version: int = 5) -> bytes:
    """The binary file of ``network``: protobuf version 5 (ISIS's ``writeProtobuf``) or 2
    (the sizes in the header, as plio's ``to_isis`` writes)."""
    if version not in (2, 5):
        raise ValueError(f"version {version}: write 2 or 5")
    header = messages().header()
    header.networkId = network.network_id
    header.targetName = network.target_name
    for name, value in (("created", network.created), ("lastModified", network.last_modified),
                        ("description", network.description),
                        ("userName", network.user_name)):
        _set(header, name, value)
    encoded = [_point_message(p).SerializeToString() for p in network.points]
    if version == 2:
        header.pointMessageSizes.extend(len(e) for e in encoded)
        body = b"".join(encoded)
    else:
        body = b"".join(struct.pack("<I", len(e)) + e for e in encoded)
    head = header.SerializeToString()
    label = _pvl_label(network, version=version, header_bytes=len(head),
                       points_start=HEADER_START_BYTE + len(head), points_bytes=len(body),
                       measures=network.measure_count).encode("ascii", "replace")
    if len(label) > HEADER_START_BYTE:
        raise ValueError("the control network's label is longer than 64 KiB")
    return label.ljust(HEADER_START_BYTE, b"\0") + head + body


def write_control_network(path: str | os.PathLike, network: ControlNetwork, *,
                          version: int = 5) -> Path:
    """Write ``network`` as a binary ISIS control network (atomic write)."""
    from demtool.outputs import atomic_path

    content = control_network_bytes(network, version=version)
    with atomic_path(path) as temporary:
        Path(temporary).write_bytes(content)
    return Path(path)


def with_points(network: ControlNetwork, points: list[ControlPoint]) -> ControlNetwork:
    """A copy of ``network`` with other points (the header kept)."""
    return replace(network, points=points)
