"""Reader fixes of issue 24: legacy VisionWorkbench .tsai, .tsai sizes from the image,
ALE's lunarorbiter keys."""

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import read_sensor, read_tsai

# ASP's examples/K10 layout: no VERSION / PINHOLE / lens-name / pitch lines; k1 k2 p1 p2
# straight after R (a TSAI lens, normalised coordinates).  Values of the same magnitude.
LEGACY = """fu = 620.857
fv = 621.045
cu = 311.111
cv = 241.268
u_direction = 1  0  0
v_direction = 0  1  0
w_direction = 0  0  1
C = -0.328 -0.0636 -0.978
R = 1 0 0 0 1 0 0 0 1
k1 = -0.235887
k2 = 0.13065
p1 = -0.000837
p2 = 0.000555
"""


def test_legacy_tsai_reads_with_an_implied_tsai_lens(tmp_path):
    path = tmp_path / "black_left.tsai"
    path.write_text(LEGACY)
    model = read_sensor(path)
    np.testing.assert_allclose(model.distortion[:4], [-0.235887, 0.13065, -0.000837, 0.000555])
    assert model.K[0, 0] == pytest.approx(620.857) and model.K[1, 2] == pytest.approx(241.268)
    # The same file with VERSION/PINHOLE/TSAI lines is the same camera.
    head, _, tail = LEGACY.partition("k1")
    modern = tmp_path / "modern.tsai"
    modern.write_text("VERSION_4\nPINHOLE\n" + head + "pitch = 1\nTSAI\nk1" + tail)
    other = read_tsai(modern)
    np.testing.assert_array_equal(model.K, other.K)
    np.testing.assert_array_equal(model.distortion, other.distortion)
    # Round trip through the lens: pixel -> ray -> pixel.
    rows, cols = np.meshgrid(np.linspace(10, 470, 5), np.linspace(10, 630, 5), indexing="ij")
    ray = model.image_to_ray(rows + 0.5, cols + 0.5)
    line, sample = model.ground_to_image(ray.origin + 5.0 * ray.direction)
    np.testing.assert_allclose(line, rows + 0.5, atol=1e-6)
    np.testing.assert_allclose(sample, cols + 0.5, atol=1e-6)


def test_legacy_tsai_with_an_unknown_key_names_the_line(tmp_path):
    path = tmp_path / "bad.tsai"
    path.write_text(LEGACY + "k7 = 0.1\n")
    with pytest.raises(InputError, match=r"bad\.tsai: line 14: unknown tsai lens parameter 'k7'"):
        read_sensor(path)


def test_rectify_takes_a_tsai_size_from_the_image(tmp_path):
    from demtool.rectify.run_sensors import read_frame_model

    path = tmp_path / "cam.tsai"
    path.write_text(LEGACY)
    model = read_frame_model(path, tmp_path / "left.png", (480, 640), "--sensor-left")
    assert model.image_size == (480, 640)


def _lo_isd(block):
    import json
    from pathlib import Path

    isd = json.loads((Path(__file__).parent / "data" / "orbitalFramer.json").read_text())
    isd["optical_distortion"] = {"lunarorbiter": block}
    return isd


LO_KEYS = {"perspective_x": 1e-4, "perspective_y": -2e-4, "center_point_x": 0.1,
           "center_point_y": -0.05}


@pytest.mark.parametrize("radial_key", ["odk", "coefficients"])
def test_lunarorbiter_isd_keys_as_ale_writes_them(radial_key):
    from demtool.sensors.isd import sensor_from_isd

    model = sensor_from_isd(_lo_isd({**LO_KEYS, radial_key: [-1e-5, 1e-8]}), "lo.json")
    np.testing.assert_allclose(model.distortion.coefficients,
                               [1e-4, -2e-4, 0.1, -0.05, -1e-5, 1e-8])
    line, sample = np.meshgrid(np.linspace(0.5, model.lines - 0.5, 4),
                               np.linspace(0.5, model.samples - 0.5, 4), indexing="ij")
    back = model.ground_to_image(model.image_to_ground(line, sample))
    np.testing.assert_allclose(back[0], line, atol=0.01)
    np.testing.assert_allclose(back[1], sample, atol=0.01)


def test_lunarorbiter_isd_without_radial_terms_is_refused_in_one_line():
    from demtool.sensors.isd import sensor_from_isd

    with pytest.raises(InputError, match=r"lo\.json: ISD lacks the key "
                                         r"'optical_distortion\.lunarorbiter\.odk'"):
        sensor_from_isd(_lo_isd(dict(LO_KEYS)), "lo.json")
    with pytest.raises(InputError, match=r"lo\.json: ISD lacks the key "
                                         r"'optical_distortion\.lunarorbiter\.center_point_y'"):
        sensor_from_isd(_lo_isd({k: v for k, v in LO_KEYS.items() if k != "center_point_y"}
                                | {"odk": [0, 0]}), "lo.json")
