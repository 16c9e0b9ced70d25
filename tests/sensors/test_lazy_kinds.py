"""``import demtool.sensors`` loads no sensor kind; reading a file loads only its kind's
modules (PEP 562 exports, :func:`demtool.lazy.lazy_exports`)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"
OTHER_KINDS = ["demtool.sensors.rpc", "demtool.sensors.rpc_files", "demtool.sensors.tsai",
               "demtool.sensors.pushframe", "demtool.sensors.cahvor_files",
               "demtool.sensors.isis_cube"]


def _loaded(code: str) -> list:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=Path(__file__).resolve().parents[2])
    return json.loads(out.stdout)


def test_reading_an_isd_loads_only_its_kind():
    before, after, kind = _loaded(
        "import json, sys\n"
        "import demtool.sensors as sensors\n"
        "before = sorted(m for m in sys.modules if m.startswith('demtool.sensors.'))\n"
        f"model = sensors.read_sensor({str(DATA / 'orbitalLineScan.json')!r})\n"
        f"after = [m for m in {OTHER_KINDS!r} if m in sys.modules]\n"
        "print(json.dumps([before, after, type(model).__name__]))\n")
    assert before == [] and after == [] and kind == "LineScanSensor"


def test_every_export_resolves():
    import demtool.sensors as sensors
    from demtool.sensors.rpc import RpcSensor
    from demtool.sensors.tsai import read_tsai

    assert sensors.RpcSensor is RpcSensor and sensors.read_tsai is read_tsai
    for name in sensors.__all__:
        assert getattr(sensors, name) is not None and name in dir(sensors)
    with pytest.raises(AttributeError, match="no attribute 'read_camera'"):
        sensors.read_camera  # noqa: B018
