"""demtool.dem.points through the sensor interface: the pixel angle and the GSD."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.dem.points import estimate_gsd, pixel_angle
from demtool.sensors.pinhole import look_at
from demtool.synth import SceneParams, make_scene


@pytest.mark.parametrize("center", [(0.0, 0.0, 1000.0), (300.0, -200.0, 900.0)])
def test_pixel_angle_of_a_pinhole_is_one_over_the_focal_length(center):
    camera = look_at(center, (0.0, 0.0, 0.0), focal_px=2000.0, width=512, height=384)
    assert pixel_angle(camera) == pytest.approx(1.0 / 2000.0, rel=1e-12)
    gsd = estimate_gsd(camera, aligned=True, depth=np.array([900.0, 1000.0, 1100.0]),
                       distance_m=None)
    assert gsd == pytest.approx(1000.0 / camera.focal_px, rel=1e-12)


def test_pixel_angle_of_planetary_sensors_gives_their_gsd():
    """Synthetic frame and line-scan sensors are built for gsd_m on the ground: range ×
    pixel angle gives it back (nadir frame exactly; the rolled line scanner's
    cross-track pixel is gsd · cos(emission) seen along its ray)."""
    params = dict(dem_size=128, n_views=2, image_size=64, gsd_m=1.0, crater_count=0,
                  boulder_count=0)
    frame = make_scene(SceneParams(sensor="frame", **params))
    target = frame.sensors[frame.target]
    assert 1000.0 * pixel_angle(target) == pytest.approx(1.0, rel=1e-9)
    linescan = make_scene(SceneParams(sensor="linescan", **params))
    model = linescan.sensors[linescan.target]
    origin = linescan.placement.origin
    line, _ = model.ground_to_image(origin)
    to_ground = origin - model.camera_center(line)
    rng = np.linalg.norm(to_ground)
    cos_e = -(to_ground / rng) @ linescan.placement.frame[2]
    assert rng * pixel_angle(model) / cos_e == pytest.approx(1.0, rel=1e-3)
