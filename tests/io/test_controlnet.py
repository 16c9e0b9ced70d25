"""ISIS control networks: the binary (protobuf V2/V5) and PVL forms read, the binary form
written and read back, checked by an independent decoder of the protobuf wire format."""

import struct
from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.io.controlnet import (
    ControlMeasure,
    ControlNetwork,
    ControlPoint,
    control_network_bytes,
    read_control_network,
    write_control_network,
)

SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
KNOTEN = SHARED / "sensors" / "ctx_knoten" / "bundle-adjust" / "controlnet.net"


def _network() -> ControlNetwork:
    cov = np.array([[4.0, 0.5, 0.1], [0.5, 9.0, -0.2], [0.1, -0.2, 16.0]])
    points = [
        ControlPoint("tie_1", "Free", [
            ControlMeasure("A/CAM/100:000", "RegisteredSubPixel", line=10.25, sample=20.75,
                           line_residual=0.1, sample_residual=-0.2, apriori_line=10.0,
                           apriori_sample=20.5, log=[(2, 0.9, None, None)]),
            ControlMeasure("B/CAM/200:000", "Manual", line=30.0, sample=40.0, ignore=True)],
            chooser_name="test", datetime="2026-01-01T00:00:00", reference_index=0,
            apriori_surface_point_source="AverageOfMeasures"),
        ControlPoint("gcp_1", "Constrained", [
            ControlMeasure("A/CAM/100:000", "Candidate", line=5.5, sample=6.5)],
            apriori_xyz=np.array([1000.0, 2000.0, 3000.0]), apriori_covariance=cov,
            adjusted_xyz=np.array([1001.0, 2001.0, 3001.0]), adjusted_covariance=2 * cov,
            latitude_constrained=True, longitude_constrained=True, radius_constrained=True),
        ControlPoint("fixed_1", "Fixed", [], ignore=True,
                     apriori_xyz=np.array([1.0, 2.0, 3.0])),
    ]
    return ControlNetwork("NET", "Mars", points, created="2026", description="a test net",
                          user_name="me")


def _assert_same(a, b):
    import dataclasses

    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert (x is None) == (y is None), f.name
            if x is not None:
                np.testing.assert_array_equal(x, y)
        elif isinstance(x, list) and x and dataclasses.is_dataclass(x[0]):
            assert len(x) == len(y)
            for u, v in zip(x, y, strict=True):
                _assert_same(u, v)
        elif f.name != "version":
            assert x == y, (f.name, x, y)


# -- an independent decoder: the protobuf wire format (varint, 64-bit, length-delimited) --


def _varint(data, pos):
    value = shift = 0
    while True:
        byte = data[pos]
        pos += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if byte < 0x80:
            return value, pos


def _fields(data):
    """(field number, wire type, value) of one message's top-level fields."""
    pos, out = 0, []
    while pos < len(data):
        key, pos = _varint(data, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(data, pos)
        elif wire == 1:
            value, pos = struct.unpack("<d", data[pos:pos + 8])[0], pos + 8
        elif wire == 2:
            length, pos = _varint(data, pos)
            value, pos = data[pos:pos + length], pos + length
        else:
            raise AssertionError(f"wire type {wire}")
        out.append((number, wire, value))
    return out


def _raw_points(blob: bytes, version: int):
    """Points of a binary network by raw wire parsing (plio's description of the layout:
    PVL label, header at 65536, then the points)."""
    text = blob[:65536].split(b"\0")[0].decode()
    values = dict(line.split("=") for line in (s.replace(" ", "") for s in text.splitlines())
                  if "Byte" in line and "=" in line)
    start, points_bytes = int(values["PointsStartByte"]), int(values["PointsBytes"])
    body = blob[start:start + points_bytes]
    points, pos = [], 0
    if version == 5:
        while pos < len(body):
            size = struct.unpack("<I", body[pos:pos + 4])[0]
            points.append(_fields(body[pos + 4:pos + 4 + size]))
            pos += 4 + size
    else:
        header = _fields(blob[65536:start])
        packed = next(v for n, w, v in header if n == 7)
        sizes, p = [], 0
        while p < len(packed):
            size, p = _varint(packed, p)
            sizes.append(size)
        for size in sizes:
            points.append(_fields(body[pos:pos + size]))
            pos += size
    return points


@pytest.mark.parametrize("version", [5, 2])
def test_written_network_reads_back_identical_and_decodes_independently(tmp_path, version):
    network = _network()
    path = write_control_network(tmp_path / "out.net", network, version=version)
    back = read_control_network(path)
    assert back.version == version
    _assert_same(network, back)
    raw = _raw_points(path.read_bytes(), version)
    assert [dict((n, v) for n, w, v in p if n in (1, 2))[1].decode() for p in raw] == \
        ["tie_1", "gcp_1", "fixed_1"]
    measures = [v for n, w, v in raw[0] if n == 25]
    first = {n: v for n, w, v in _fields(measures[0])}
    # ISIS pixel coordinates are 1-based at the pixel centre: demtool's + 0.5
    assert first[3] == pytest.approx(21.25) and first[4] == pytest.approx(10.75)
    assert first[1].decode() == "A/CAM/100:000"
    covar = [v for n, w, v in raw[1] if n == 19][0]
    assert struct.unpack("<6d", covar) == (4.0, 0.5, 0.1, 9.0, -0.2, 16.0)
    assert dict((n, v) for n, w, v in raw[1])[2] == 3  # Constrained


def test_pvl_form_reads_like_the_binary_form(tmp_path):
    text = """Object = ControlNetwork
  NetworkId    = NET
  TargetName   = Mars
  UserName     = me
  Created      = 2026
  LastModified = 2026
  Description  = "a test net"
  Version      = 5

  Object = ControlPoint
    PointType  = Constrained
    PointId    = gcp_1
    AprioriX   = 1000.0 <meters>
    AprioriY   = 2000.0 <meters>
    AprioriZ   = 3000.0 <meters>
    AprioriCovarianceMatrix = (4.0, 0.5, 0.1, 9.0, -0.2, 16.0)
    LatitudeConstrained = True

    Group = ControlMeasure
      SerialNumber = A/CAM/100:000
      MeasureType  = Candidate
      Sample       = 7.0
      Line         = 6.0
    End_Group

    Group = ControlMeasure
      SerialNumber = B/CAM/200:000
      MeasureType  = RegisteredSubPixel
      Ignore       = True
      Sample       = 1.5
      Line         = 2.5
      Reference    = True
    End_Group
  End_Object

  Object = ControlPoint
    PointType = Ground
    PointId   = old_ground
    AprioriX  = 1.0 <meters>
    AprioriY  = 2.0 <meters>
    AprioriZ  = 3.0 <meters>
  End_Object
End_Object
End
"""
    path = tmp_path / "net.pvl"
    path.write_text(text)
    network = read_control_network(path)
    assert [p.type for p in network.points] == ["Constrained", "Fixed"]
    point = network.points[0]
    assert point.measures[0].line == 5.5 and point.measures[0].sample == 6.5
    assert point.measures[1].ignored and point.reference_index == 1
    np.testing.assert_array_equal(point.apriori_covariance[1], [0.5, 9.0, -0.2])
    back = read_control_network(write_control_network(tmp_path / "b.net", network))
    _assert_same(network, back)


def test_not_a_network_and_truncated_files_are_one_line_errors(tmp_path):
    bad = tmp_path / "bad.net"
    bad.write_text("hello\n")
    with pytest.raises(InputError, match="not an ISIS control network"):
        read_control_network(bad)
    blob = control_network_bytes(_network())
    cut = tmp_path / "cut.net"
    cut.write_bytes(blob[:-10])
    with pytest.raises(InputError, match="truncated"):
        read_control_network(cut)


@pytest.mark.skipif(not KNOTEN.exists(), reason="needs ../shared/data")
def test_knoten_ctx_network_reads_449_points_930_measures(tmp_path):
    network = read_control_network(KNOTEN)
    assert (network.network_id, network.target_name) == ("SYRTIS_MAJOR_CTX", "Mars")
    assert len(network.points) == 449 and network.measure_count == 930
    assert sorted(network.serials()) == ["MRO/CTX/0884541979:200", "MRO/CTX/0891288961:044",
                                         "MRO/CTX/1016816309:030"]
    first = network.points[0].measures[0]
    assert (first.sample, first.line) == (849.5, 24.5)  # ISIS 850, 25
    blob = control_network_bytes(network)
    assert blob[65536:] == KNOTEN.read_bytes()[65536:]  # header and points byte for byte
