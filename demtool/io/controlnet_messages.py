"""The protobuf messages of ISIS control networks, built at run time from their definitions.

The definitions are ISIS's own (DOI-USGS/ISIS3 ``isis/src/control/objs/
ControlNetVersioner/``): ``ControlNetFileHeaderV0002.proto`` (the header of version 2
files, with ``pointMessageSizes``; version 5 files use the same fields without it,
``ControlNetFileHeaderV0005.proto``) and ``ControlPointFileEntryV0002.proto`` (one
message per control point, the same in version 2 and 5 files;
``ControlPointFileEntryV0005.proto`` repeats it field for field).  They are described
here as a :class:`google.protobuf.descriptor_pb2.FileDescriptorProto` in a private
descriptor pool, so no generated ``_pb2`` module and no ``protoc`` is needed and another
library that registers ``Isis.*`` messages (plio) does not clash.
"""

from __future__ import annotations

from functools import lru_cache
from types import SimpleNamespace

#: field types of descriptor_pb2.FieldDescriptorProto
_TYPES = {"double": 1, "int32": 5, "bool": 8, "string": 9, "message": 11, "enum": 14}
_LABELS = {"optional": 1, "required": 2, "repeated": 3}

POINT_TYPES = {"Free": 2, "Constrained": 3, "Fixed": 4, "obsolete_Tie": 0,
               "obsolete_Ground": 1}
APRIORI_SOURCES = {"None": 0, "User": 1, "AverageOfMeasures": 2, "Reference": 3,
                   "Ellipsoid": 4, "DEM": 5, "Basemap": 6, "BundleSolution": 7}
MEASURE_TYPES = {"Candidate": 0, "Manual": 1, "RegisteredPixel": 2, "RegisteredSubPixel": 3}

_LOG_FIELDS = [("doubleDataType", "int32", 1), ("doubleDataValue", "double", 2),
               ("boolDataType", "int32", 3), ("boolDataValue", "bool", 4)]

#: ControlPointFileEntryV0002.Measure: (name, label, type, number[, type name])
MEASURE_FIELDS = [
    ("serialnumber", "required", "string", 1), ("type", "required", "enum", 2, "MeasureType"),
    ("sample", "optional", "double", 3), ("line", "optional", "double", 4),
    ("sampleResidual", "optional", "double", 5), ("lineResidual", "optional", "double", 6),
    ("choosername", "optional", "string", 7), ("datetime", "optional", "string", 8),
    ("editLock", "optional", "bool", 9), ("ignore", "optional", "bool", 10),
    ("jigsawRejected", "optional", "bool", 11), ("diameter", "optional", "double", 12),
    ("apriorisample", "optional", "double", 13), ("aprioriline", "optional", "double", 14),
    ("samplesigma", "optional", "double", 15), ("linesigma", "optional", "double", 16),
    ("log", "repeated", "message", 17, "MeasureLogData"),
]

#: ControlPointFileEntryV0002
POINT_FIELDS = [
    ("id", "required", "string", 1), ("type", "required", "enum", 2, "PointType"),
    ("chooserName", "optional", "string", 3), ("datetime", "optional", "string", 4),
    ("editLock", "optional", "bool", 5), ("ignore", "optional", "bool", 6),
    ("jigsawRejected", "optional", "bool", 7), ("referenceIndex", "optional", "int32", 8),
    ("aprioriSurfPointSource", "optional", "enum", 9, "AprioriSource"),
    ("aprioriSurfPointSourceFile", "optional", "string", 10),
    ("aprioriRadiusSource", "optional", "enum", 11, "AprioriSource"),
    ("aprioriRadiusSourceFile", "optional", "string", 12),
    ("latitudeConstrained", "optional", "bool", 13),
    ("longitudeConstrained", "optional", "bool", 14),
    ("radiusConstrained", "optional", "bool", 15),
    ("aprioriX", "optional", "double", 16), ("aprioriY", "optional", "double", 17),
    ("aprioriZ", "optional", "double", 18), ("aprioriCovar", "repeated", "double", 19),
    ("adjustedX", "optional", "double", 20), ("adjustedY", "optional", "double", 21),
    ("adjustedZ", "optional", "double", 22), ("adjustedCovar", "repeated", "double", 23),
    ("log", "repeated", "message", 24, "PointLogData"),
    ("measures", "repeated", "message", 25, "Measure"),
]

HEADER_FIELDS = [
    ("networkId", "required", "string", 1), ("targetName", "required", "string", 2),
    ("created", "optional", "string", 3), ("lastModified", "optional", "string", 4),
    ("description", "optional", "string", 5), ("userName", "optional", "string", 6),
    ("pointMessageSizes", "repeated", "int32", 7),
]


def _add_fields(message, fields, scope: str) -> None:
    for name, label, kind, number, *type_name in fields:
        field = message.field.add(name=name, number=number, label=_LABELS[label],
                                  type=_TYPES[kind])
        if type_name:
            field.type_name = f".{scope}.{type_name[0]}"
        if name in ("aprioriCovar", "adjustedCovar", "pointMessageSizes"):
            field.options.packed = True


def _add_enum(message, name: str, values: dict[str, int]) -> None:
    enum = message.enum_type.add(name=name)
    for value_name, number in values.items():
        enum.value.add(name=value_name, number=number)


@lru_cache(maxsize=1)
def messages() -> SimpleNamespace:
    """The message classes: ``header`` (ControlNetFileHeaderV0002) and ``point``
    (ControlPointFileEntryV0002, with ``point.Measure``)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    proto = descriptor_pb2.FileDescriptorProto(name="demtool/isis_controlnet_v0002.proto",
                                               package="Isis", syntax="proto2")
    header = proto.message_type.add(name="ControlNetFileHeaderV0002")
    _add_fields(header, HEADER_FIELDS, "Isis.ControlNetFileHeaderV0002")
    point = proto.message_type.add(name="ControlPointFileEntryV0002")
    scope = "Isis.ControlPointFileEntryV0002"
    _add_enum(point, "PointType", POINT_TYPES)
    _add_enum(point, "AprioriSource", APRIORI_SOURCES)
    log = point.nested_type.add(name="PointLogData")
    _add_fields(log, [(n, "optional", k, i) for n, k, i in _LOG_FIELDS], scope)
    measure = point.nested_type.add(name="Measure")
    _add_enum(measure, "MeasureType", MEASURE_TYPES)
    measure_log = measure.nested_type.add(name="MeasureLogData")
    _add_fields(measure_log, [(n, "optional", k, i) for n, k, i in _LOG_FIELDS], scope)
    _add_fields(measure, MEASURE_FIELDS, f"{scope}.Measure")
    _add_fields(point, POINT_FIELDS, scope)
    pool = descriptor_pool.DescriptorPool()
    pool.Add(proto)
    get = message_factory.GetMessageClass
    return SimpleNamespace(
        header=get(pool.FindMessageTypeByName("Isis.ControlNetFileHeaderV0002")),
        point=get(pool.FindMessageTypeByName(scope)))
