"""Bundle adjustment with pose priors: synthetic frame block with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.bundle.offsets import PoseOffset, rotation_matrices, rotation_vector
from demtool.bundle.priors import AdjustedSensor, adjust_with_priors, triangulate
from demtool.errors import ProcessingError
from tests.bundle import frames


def _errors(prior, truth, offsets):
    """Position (m) and pointing (mrad) errors of the adjusted models against the truth."""
    position, pointing = [], []
    for p, t, off in zip(prior, truth, offsets, strict=True):
        adjusted = AdjustedSensor(p, off)
        position.append(np.linalg.norm(adjusted.camera_center(0.5) - t.position))
        pointing.append(np.linalg.norm(rotation_vector(off.matrix @ p.rotation
                                                       @ t.rotation.T)) * 1e3)
    return np.array(position), np.array(pointing)


@pytest.fixture(scope="module")
def block():
    truth = frames.true_models(size=4000)
    obs, xyz = frames.tie_observations(truth, count=6000)
    return truth, obs, xyz


def test_rotation_vector_roundtrip():
    w = np.array([1e-3, -2e-3, 0.5])
    assert np.allclose(rotation_vector(rotation_matrices(w)), w, atol=1e-12)
    assert np.allclose(rotation_matrices(np.zeros(3)), np.eye(3))


def test_adjusted_sensor_is_the_moved_camera():
    model = frames.true_models(size=400)[0]
    offset = PoseOffset(np.array([10.0, -5.0, 3.0]), np.array([2e-4, -1e-4, 3e-4]),
                        model.position)
    adjusted = AdjustedSensor(model, offset)
    moved = frames.FrameSensor(position=model.position + offset.translation,
                               rotation=offset.matrix @ model.rotation,
                               focal_length=model.focal_length, detector=model.detector,
                               lines=model.lines, samples=model.samples, radii=model.radii)
    lines, samples = np.meshgrid([10.5, 200.5, 390.5], [5.5, 100.5, 395.5])
    ground = moved.image_to_ground(lines, samples)
    assert np.allclose(adjusted.image_to_ground(lines, samples), ground, atol=1e-4)
    line, sample = adjusted.ground_to_image(ground)
    assert np.allclose(line, lines, atol=1e-7) and np.allclose(sample, samples, atol=1e-7)


def test_triangulate_recovers_points(block):
    truth, obs, xyz = block
    points, miss = triangulate(truth, obs)
    # observations carry 0.2 px noise at 5.5 m per pixel (1.1 m on the ground)
    error = np.linalg.norm(points - xyz, axis=1)
    assert np.median(error) < 3.0
    assert np.median(miss) < 2.0


def test_priors_recover_perturbed_frames(block):
    """Positions 50 m and pointing 0.5 mrad off (zero mean over the block): adjusted
    within 5 m / 0.05 mrad of the truth (issue 14)."""
    truth, obs, _ = block
    prior = frames.perturbed(truth, position_m=50.0, pointing_mrad=0.5)
    before = _errors(prior, truth, [PoseOffset(np.zeros(3), np.zeros(3), p.position)
                                    for p in prior])
    assert np.allclose(before[0], 50.0) and np.allclose(before[1], 0.5)
    result = adjust_with_priors(prior, obs, position_sigma=50.0, pointing_sigma=0.5)
    position, pointing = _errors(prior, truth, result.offsets)
    assert position.max() < 5.0, position
    assert pointing.max() < 0.05, pointing
    assert result.initial_rms_px > 3.0
    assert np.sqrt(np.mean(np.sum(result.residuals ** 2, axis=1))) < 0.35
    report = result.image_report([p.name for p in prior])
    assert set(report) == {p.name for p in prior}
    first = report[prior[0].name]
    assert first["observations"] > 1000
    assert 40.0 < first["position_change_m"] < 60.0
    assert 0.3 < first["pointing_change_mrad"] < 0.7


def test_common_offset_stays(block):
    """The same offset for every image is the block's datum: tie points cannot see it,
    so the adjusted block keeps it (the relative geometry stays right)."""
    truth, obs, _ = block
    prior = frames.perturbed(truth, position_m=50.0, pointing_mrad=0.0, zero_mean=False,
                             common=True)
    result = adjust_with_priors(prior, obs, position_sigma=50.0, pointing_sigma=0.5)
    shifts = np.array([AdjustedSensor(p, o).camera_center(0.5) - t.position
                       for p, o, t in zip(prior, result.offsets, truth, strict=True)])
    assert np.allclose(np.linalg.norm(shifts, axis=1), 50.0, atol=5.0)
    assert np.max(np.linalg.norm(shifts - shifts.mean(axis=0), axis=1)) < 5.0


def test_image_without_ties_fails(block):
    truth, obs, _ = block
    keep = obs.image != 3
    with pytest.raises(ProcessingError, match="frame_03"):
        adjust_with_priors(truth, obs.subset(keep), position_sigma=50.0, pointing_sigma=0.5)
