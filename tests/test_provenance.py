"""Provenance tags and the <output>.json sidecar."""

import hashlib
import json

import numpy as np

from demtool import __version__
from demtool import io as dio
from demtool.provenance import Provenance


def test_sidecar_records_inputs_with_hashes_params_time_and_summary(tmp_path):
    source = tmp_path / "in.tif"
    dio.write_raster(source, np.ones((4, 4)))
    prov = Provenance("sgm", {"p1": 8, "out": tmp_path / "d.tif"}, [source])
    output = tmp_path / "d.tif"
    with dio.output_transaction():
        dio.write_raster(output, np.zeros((4, 4)), tags=prov.tags(frame="image:x"))
        sidecar = prov.write_sidecar(output, {"valid_fraction": 0.9})
    record = json.loads(sidecar.read_text())
    assert sidecar.name == "d.tif.json"
    assert record["stage"] == "sgm" and record["demtool_version"] == __version__
    assert record["parameters"] == {"p1": 8, "out": str(output)}
    assert record["inputs"][0]["sha256"] == hashlib.sha256(source.read_bytes()).hexdigest()
    assert record["summary"] == {"valid_fraction": 0.9}
    assert record["wall_time_s"] >= 0 and record["peak_memory_mb"] > 10
    raster = dio.read_raster(output)
    assert raster.tags["demtool_stage"] == "sgm"
    assert raster.tag_json("demtool_params")["p1"] == 8
    assert raster.tag_json("demtool_inputs") == ["in.tif"]
    assert raster.tags["frame"] == "image:x"
