"""Adjusted models written back: ISD (with a real body rotation), cube-made ISD, .tsai."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from demtool.bundle.offsets import PoseOffset, pivot_of
from demtool.bundle.priors import AdjustedSensor
from demtool.bundle.writeback import adjust_isd, adjust_tsai, model_isd
from demtool.sensors import FrameSensor, read_tsai, sensor_from_isd
from tests.bundle import frames

DATA = Path(__file__).resolve().parents[1] / "sensors" / "data"
OFFSET_T = np.array([12.0, -30.0, 7.5])
OFFSET_W = np.array([3e-4, -2e-4, 4e-4])


def _same_geometry(a, b, *, ground_tol=1e-3, pixel_tol=1e-6):
    lines = np.array([0.5, 0.3 * a.lines, 0.7 * a.lines, a.lines - 0.5])
    samples = np.array([0.5, 0.6 * a.samples, 0.2 * a.samples, a.samples - 0.5])
    ground = a.image_to_ground(lines, samples)
    assert np.allclose(b.image_to_ground(lines, samples), ground, atol=ground_tol, rtol=0)
    line, sample = b.ground_to_image(ground)
    assert np.allclose(line, lines, atol=pixel_tol) and np.allclose(sample, samples,
                                                                    atol=pixel_tol)


def test_model_isd_reads_back_as_the_same_model():
    model = frames.true_models(size=500)[2]
    _same_geometry(model, sensor_from_isd(json.loads(json.dumps(model_isd(model)))))


def test_model_isd_looking_along_minus_z():
    """ISIS's zDirection = −1 (Apollo Metric) is written as the +z camera turned 180°."""
    m = frames.true_models(size=500)[1]
    flipped = FrameSensor(position=m.position, rotation=m.rotation @ np.diag([-1.0, -1, 1]),
                          focal_length=m.focal_length, detector=m.detector, lines=m.lines,
                          samples=m.samples, radii=m.radii, z_direction=-1.0)
    _same_geometry(flipped, m)
    _same_geometry(flipped, sensor_from_isd(model_isd(flipped)))


def test_adjust_isd_with_body_rotation_is_the_adjusted_model():
    """usgscsm's orbitalFramer: J2000 states and a rotating body frame."""
    isd = json.loads((DATA / "orbitalFramer.json").read_text())
    model = sensor_from_isd(isd)
    offset = PoseOffset(OFFSET_T, OFFSET_W, pivot_of(model))
    adjusted = sensor_from_isd(adjust_isd(isd, offset))
    assert np.allclose(adjusted.position, model.position + OFFSET_T, atol=1e-6)
    assert np.allclose(adjusted.rotation, offset.matrix @ model.rotation, atol=1e-12)
    _same_geometry(AdjustedSensor(model, offset), adjusted)


def test_adjust_tsai(tmp_path):
    text = ("VERSION_4\nPINHOLE\nfu = 20\nfv = 20\ncu = 5.12\ncv = 5.12\n"
            "u_direction = 1 0 0\nv_direction = 0 1 0\nw_direction = 0 0 1\n"
            "C = 1837400 0 0\nR = 0 0 -1 1 0 0 0 -1 0\npitch = 0.01\nNULL\n")
    source = tmp_path / "cam.tsai"
    source.write_text(text)
    radii = (1737400.0, 1737400.0)
    model = read_tsai(source, radii=radii)
    offset = PoseOffset(OFFSET_T, OFFSET_W, np.array([1837400.0, 0, 0]))
    out = tmp_path / "adjusted.tsai"
    out.write_text(adjust_tsai(text, offset))
    adjusted = read_tsai(out, radii=radii)
    assert np.allclose(adjusted.center, [1837412.0, -30.0, 7.5])
    assert "pitch = 0.01" in out.read_text()
    points = np.array([[1737400.0, 100.0, -50.0], [1737390.0, -300.0, 200.0]])
    ref = AdjustedSensor(model, offset)
    assert np.allclose(np.stack(adjusted.ground_to_image(points)),
                       np.stack(ref.ground_to_image(points)), atol=1e-6)


def test_adjust_line_scan_isd_moves_the_whole_trajectory():
    """usgscsm's orbitalLineScan: every ephemeris and attitude record is moved alike."""
    isd = json.loads((DATA / "orbitalLineScan.json").read_text())
    model = sensor_from_isd(isd)
    offset = PoseOffset(OFFSET_T, OFFSET_W, pivot_of(model))
    adjusted = sensor_from_isd(adjust_isd(isd, offset))
    # ground to 1 mm, image to 1e-4 px (the reader resamples the records it is given)
    _same_geometry(AdjustedSensor(model, offset), adjusted, ground_tol=1e-3, pixel_tol=1e-4)
