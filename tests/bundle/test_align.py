"""`demtool bundle`: pycolmap SfM, conventions, alignment, errors."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from demtool import bundle as core
from demtool.errors import ProcessingError
from demtool.sensors.pinhole import PinholeCamera, look_at, to_pycolmap


def rotation(ax: float, ay: float, az: float) -> np.ndarray:
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    return (np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
            @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
            @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]))


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(0)
    source = rng.normal(size=(6, 3)) * 10
    R = rotation(0.3, -0.7, 1.9)
    target = 3.7 * source @ R.T + np.array([100.0, -20.0, 5.0])
    scale, R_est, t_est = core.umeyama(source, target)
    assert scale == pytest.approx(3.7, rel=1e-12)
    np.testing.assert_allclose(R_est, R, atol=1e-12)
    np.testing.assert_allclose(t_est, [100.0, -20.0, 5.0], atol=1e-9)
    assert np.linalg.det(R_est) == pytest.approx(1.0)


def test_umeyama_rejects_too_few_and_collinear_centres():
    with pytest.raises(ProcessingError, match="at least 3"):
        core.umeyama(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.outer(np.arange(4.0), [1.0, 2.0, 0.5])
    with pytest.raises(ProcessingError, match="collinear"):
        core.umeyama(line, line * 2)


def make_result(n_points: int = 50) -> core.BundleResult:
    rng = np.random.default_rng(1)
    points = np.column_stack([rng.uniform(-20, 20, (n_points, 2)), rng.normal(0, 1, n_points)])
    cameras = [look_at([x, y, 300.0], [0, 0, 0], focal_px=800, width=200, height=150)
               for x, y in [(0, 0), (60, 0), (0, 70), (-50, -40)]]
    return core.BundleResult(points=points, colors=np.ones(n_points),
                             track_length=np.full(n_points, 3),
                             reprojection_error=np.full(n_points, 0.1),
                             image_names=np.array(["a", "b", "c", "d"]), cameras=cameras,
                             distortion=np.zeros((4, 2)), target_index=0)


def test_similarity_keeps_projections_and_alignment_recovers_centres():
    truth = make_result()
    R = rotation(0.1, 0.2, -0.4)
    # A model frame: scaled, rotated and shifted copy of the truth.
    inverse_scale, inverse_R, inverse_t = 0.02, R, np.array([1.0, 2.0, 3.0])
    model = core.apply_similarity(truth, inverse_scale, inverse_R, inverse_t)
    for cam_truth, cam_model in zip(truth.cameras, model.cameras, strict=True):
        np.testing.assert_allclose(cam_model.project(model.points),
                                   cam_truth.project(truth.points), atol=1e-9)
    centres = {str(n): c.center for n, c in zip(truth.image_names, truth.cameras, strict=True)}
    aligned, report = core.align_to_centres(
        core.BundleResult(**{**model.__dict__, "aligned": False}), centres)
    assert aligned.aligned
    assert report["scale"] == pytest.approx(1 / inverse_scale)
    assert report["centre_rms_m"] < 1e-9
    np.testing.assert_allclose(aligned.points, truth.points, atol=1e-8)


def test_alignment_needs_three_known_centres():
    result = make_result()
    with pytest.raises(ProcessingError, match="at least 3 registered images"):
        core.align_to_centres(result, {"a": np.zeros(3), "b": np.ones(3), "zz": np.ones(3)})


@pytest.mark.parametrize("model, extra", [("SIMPLE_PINHOLE", []), ("SIMPLE_RADIAL", [-0.05]),
                                          ("RADIAL", [0.03, -0.01])])
def test_projection_matches_colmap_with_half_pixel_convention(model, extra):
    """demtool's K (pixel centres at integers) + distortion reproduce COLMAP's projection
    of the same camera shifted by 0.5 px (COLMAP puts the first pixel centre at 0.5)."""
    import pycolmap

    from demtool.sensors.pinhole import from_pycolmap

    camera = look_at([30.0, -20.0, 400.0], [0, 0, 0], focal_px=900, width=320, height=240)
    colmap_camera, pose = to_pycolmap(camera)
    f = camera.K[0, 0]
    params = [f, camera.K[0, 2] + 0.5, camera.K[1, 2] + 0.5, *extra]
    colmap_camera = pycolmap.Camera(model=model, width=320, height=240, params=params,
                                    camera_id=1)
    image = SimpleNamespace(cam_from_world=pose)  # a registered pycolmap Image's pose
    converted = from_pycolmap(image, colmap_camera)
    np.testing.assert_allclose(converted.K, camera.K, atol=1e-12)
    np.testing.assert_allclose(converted.R, camera.R, atol=1e-12)
    distortion = core.radial_terms(colmap_camera)
    rng = np.random.default_rng(2)
    points = np.column_stack([rng.uniform(-60, 60, (20, 2)), rng.normal(0, 3, 20)])
    ours, depth = core.project_points(converted, points, distortion)
    cam_points = points @ camera.R.T + camera.t
    colmap = np.array([colmap_camera.img_from_cam(p) for p in cam_points])
    np.testing.assert_allclose(ours, colmap - 0.5, atol=1e-9)
    np.testing.assert_allclose(depth, cam_points[:, 2])


def test_known_intrinsics_are_written_to_colmap(tmp_path):
    """--cameras intrinsics reach COLMAP with the +0.5 px principal-point shift."""
    camera = PinholeCamera(K=[[850.0, 0, 99.5], [0, 860.0, 74.5], [0, 0, 1]], R=np.eye(3),
                           t=np.zeros(3), width=200, height=150)
    text = core.colmap_camera_params("PINHOLE", camera.K)
    assert [float(v) for v in text.split(",")] == [850.0, 860.0, 100.0, 75.0]
    text = core.colmap_camera_params("RADIAL", camera.K)
    assert [float(v) for v in text.split(",")] == [855.0, 100.0, 75.0, 0.0, 0.0]
