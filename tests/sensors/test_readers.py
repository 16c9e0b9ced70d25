"""read_sensor dispatch, the ISIS cube reader's bad inputs, and the Apollo 15 cubes."""

from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import FrameSensor, LineScanSensor, read_sensor

DATA = Path(__file__).parent / "data"
CUBES = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "sensors" \
    / "apollo15_cubes"

LABEL = """Object = IsisCube
  Object = Core
    StartByte   = 65537
    Format      = Tile
    Group = Dimensions
      Samples = 4
      Lines   = 4
      Bands   = 1
    End_Group
  End_Object
  Group = Kernels
    NaifFrameCode = -915240
  End_Group
End_Object
End
"""


def test_dispatch_on_content():
    assert isinstance(read_sensor(DATA / "orbitalFramer.json"), FrameSensor)
    assert isinstance(read_sensor(DATA / "orbitalLineScan.json"), LineScanSensor)


def test_unknown_content(tmp_path):
    path = tmp_path / "camera.txt"
    path.write_text("hello")
    with pytest.raises(InputError, match="camera.txt: not a sensor model"):
        read_sensor(path)


def test_cube_without_spice_says_spiceinit(tmp_path):
    path = tmp_path / "raw.cub"
    path.write_bytes(LABEL.encode() + b"\0" * 64)
    with pytest.raises(InputError, match=r"raw\.cub.*spiceinit.*attach=true"):
        read_sensor(path)


def test_cube_with_empty_table(tmp_path):
    table = """Object = Table
  Name = {name}
  StartByte = 1
  Records = 0
  ByteOrder = Lsb
  Group = Field
    Name = ET
    Type = Double
    Size = 1
  End_Group
End_Object
"""
    tables = "".join(table.format(name=n) for n in
                     ("InstrumentPointing", "InstrumentPosition", "BodyRotation", "SunPosition"))
    naif = "Object = NaifKeywords\n  INS-915240_FOCAL_LENGTH = 76.0\nEnd_Object\n"
    text = LABEL.replace("End\n", tables + naif + "End\n")
    path = tmp_path / "empty.cub"
    path.write_bytes(text.encode() + b"\0" * 64)
    with pytest.raises(InputError, match=r"empty\.cub.*InstrumentPointing is empty"):
        read_sensor(path)


@pytest.mark.data
def test_apollo15_cubes_geometry():
    paths = sorted(CUBES.glob("*.cub"))
    if len(paths) < 2:
        pytest.skip("../shared/data/sensors/apollo15_cubes is absent")
    left, right = (read_sensor(p) for p in paths[:2])
    altitude = np.linalg.norm(left.position) - left.radii[0]
    base = np.linalg.norm(left.position - right.position)
    assert 115e3 < altitude < 123e3                      # ≈ 119 km
    assert base / altitude == pytest.approx(0.34, abs=0.02)
    # The footprints overlap: a grid of the left image lands inside the right one.
    lines, samples = np.meshgrid(np.arange(25, 500, 50.0), np.arange(25, 500, 50.0))
    line, sample = right.ground_to_image(left.image_to_ground(lines, samples))
    inside = (line > 0) & (line < 500) & (sample > 0) & (sample < 500)
    assert inside.mean() > 0.5
    # Through the AlphaCube window, the crops' mutual shift is tens of pixels (the
    # windows absorb the ~5000 px stereo shift of the full scans); the line shift
    # agrees with the SIFT shift (−64.8 px) within 6 px.
    assert np.median(line[inside] - lines[inside]) == pytest.approx(-64.8, abs=6.0)
    assert 0 < np.median(sample[inside] - samples[inside]) < 100
