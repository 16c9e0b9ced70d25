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
from dataclasses import replace
from pathlib import Path

import numpy as np

from demtool.errors import InputError
from demtool.io.controlnet_messages import (
    APRIORI_SOURCES,
    MEASURE_TYPES,
    POINT_TYPES,
    messages,
)
from demtool.io.controlnet_model import (  # noqa: F401  (part of this interface)
    _OBSOLETE,
    HEADER_START_BYTE,
    ISIS_PIXEL_OFFSET,
    ControlMeasure,
    ControlNetwork,
    ControlPoint,
    _covariance,
    _shift,
    _triangle,
)

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
        from demtool.io.controlnet_pvl import read_pvl_network

        label = _parse_pvl(data.decode("latin-1"), source)
        if "ControlNetwork" in label:
            return read_pvl_network(label, source)
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
