"""A local rig whose models are a few pixels off its images (demtool.rectify.relative_pose)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from demtool.errors import ProcessingError
from demtool.rectify.calibrated import rectified_geometry, rectify_sensors
from demtool.rectify.relative_pose import correct_local_pose, fit_relative_pose
from demtool.sensors.arrays import rotation_vector_matrix
from demtool.sensors.pinhole import PinholeCamera, look_at


def _rig():
    """Two cameras 1 m above the ground, 0.3 m apart, pitched 25° down (a rover's mast)."""
    look = np.array([0.0, np.cos(np.radians(25)), -np.sin(np.radians(25))])
    cams = []
    for x in (-0.15, 0.15):
        c = np.array([x, 0.0, 1.0])
        cams.append(look_at(c, c + look, up=(0, 0, 1), focal_px=448.0, width=320, height=240))
    return cams


def _matches(left, right, count=600, noise=0.2, seed=0):
    """Pixels (x, y) of ground points 1.5-6 m ahead seen by both, with noise (px)."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(-2, 2, 4 * count), rng.uniform(1.5, 6, 4 * count),
                           rng.uniform(-0.2, 0.3, 4 * count)])
    pl, pr = left.project(xyz), right.project(xyz)
    ok = np.all((pl > 2) & (pl < [318, 238]) & (pr > 2) & (pr < [318, 238]), axis=1)
    pl, pr = pl[ok][:count], pr[ok][:count]
    return pl + rng.normal(0, noise, pl.shape), pr + rng.normal(0, noise, pr.shape)


def _turned(camera, omega_world):
    R = camera.R @ rotation_vector_matrix(omega_world).T
    return PinholeCamera(K=camera.K, R=R, t=-R @ camera.center, width=camera.width,
                         height=camera.height)


def test_a_yaw_and_roll_of_the_right_camera_are_recovered_from_the_rows():
    left, right = _rig()
    pl, pr = _matches(left, right)
    # the model's right camera is turned by a yaw of 4 mrad (about up) and a roll of
    # 5 mrad (about its boresight): the images are the exact rig's
    omega = 4e-3 * np.array([0, 0, 1.0]) + 5e-3 * right.axis
    wrong = _turned(right, omega)
    geometry = rectified_geometry(left, wrong)
    fit = fit_relative_pose(left, wrong, geometry.R_rect, geometry.f_px, pl, pr,
                            baseline=False)
    # the fitted rotation undoes the error (rectified frame): about the baseline and the
    # boresight within 0.3 mrad; about the rectified y axis (seen in the rows only through
    # perspective, ω_y x y / f) within 1.2 mrad of 3.6 (σ 0.5 mrad at 0.2 px, 600 matches)
    error = fit.omega_rect - geometry.R_rect @ (-omega)
    assert np.all(np.abs(error[[0, 2]]) < 3e-4) and abs(error[1]) < 1.2e-3
    assert fit.rms_after < 0.32  # the noise: 0.2 px in each image, √2 · 0.2 across rows
    before = float(np.sqrt(np.mean(fit.residuals_before ** 2)))
    result, triangulating, rectifying = correct_local_pose(
        left, wrong, geometry.R_rect, geometry.f_px, pl, pr, before, max_residual_px=1.0,
        max_pointing_mrad=10.0, systematic_px=0.5, what="rig")
    assert result is not None and rectifying is None
    # the corrected model looks where the true one does (6.4 mrad off before)
    angle = np.arccos(np.clip((np.trace(triangulating.R @ right.R.T) - 1) / 2, -1, 1))
    assert angle < 1.2e-3


def test_an_exact_rig_is_left_as_it_is():
    left, right = _rig()
    pl, pr = _matches(left, right, seed=1)
    geometry = rectified_geometry(left, right)
    fit = fit_relative_pose(left, right, geometry.R_rect, geometry.f_px, pl, pr,
                            baseline=False)
    before = float(np.sqrt(np.mean(fit.residuals_before ** 2)))
    result, triangulating, rectifying = correct_local_pose(
        left, right, geometry.R_rect, geometry.f_px, pl, pr, before, max_residual_px=1.0,
        max_pointing_mrad=10.0, systematic_px=0.5, what="rig")
    assert result is None and triangulating is right and rectifying is None


def test_an_error_no_rotation_explains_rectifies_by_a_pose_and_triangulates_as_given():
    left, right = _rig()
    pl, pr = _matches(left, right, seed=2)
    # the model's right camera 2 cm lower than the true one: rows off by a depth-dependent
    # amount (f · 0.02 / depth: 1.5 px at 6 m, 6 px at 1.5 m) that no rotation explains
    wrong = dataclasses.replace(right, t=-right.R @ (right.center + [0, 0, -0.02]))
    result = rectify_sensors(left, wrong, pl, pr, what="rig")
    assert result.corrected and result.right_model is wrong
    assert result.rectifying_right is not wrong
    rows = result.points_left_rect[:, 1] - result.points_right_rect[:, 1]
    assert np.sqrt(np.mean(rows ** 2)) < 0.4  # the noise: 0.28 px across rows
    assert len(rows) > 0.9 * len(pl)


def test_a_pair_no_pose_rectifies_is_refused_in_one_line():
    left, right = _rig()
    pl, pr = _matches(left, right, seed=3)
    rng = np.random.default_rng(4)
    pr = pr + rng.normal(0, 3.0, pr.shape)  # 3 px of noise: no pose brings rows within 1 px
    with pytest.raises(ProcessingError, match="relative pose is off") as info:
        rectify_sensors(left, right, pl, pr, what="rig")
    assert "\n" not in str(info.value)


@pytest.mark.slow
def test_a_rig_off_by_a_yaw_and_a_roll_gives_the_exact_rigs_dem(tmp_path):
    """Issue 43: a known relative-pose error (yaw 4 mrad, roll 5 mrad of the right camera:
    1.8 px along the rows, up to 0.8 px across) → DEM RMSE within 1.5× the exact rig's."""
    import json

    from demtool import io as dio
    from demtool.dem.params import DemParams
    from demtool.dem.run import run_dem
    from demtool.rectify.params import RectifyParams
    from demtool.rectify.run import run_rectify
    from demtool.sensors.pinhole import cameras_to_arrays
    from demtool.sgm.params import SgmParams
    from demtool.sgm.run import run_sgm
    from tests.helpers.rover import local_dem_errors, write_rover_pair

    scene = write_rover_pair(tmp_path, supersample=1, width=256, height=192, focal_px=358.4)
    omega = 4e-3 * np.array([0, 0, 1.0]) + 5e-3 * scene.right.axis
    rmse, residuals = {}, {}
    for label, right in (("exact", scene.right), ("off", _turned(scene.right, omega))):
        cameras = tmp_path / f"{label}.npz"
        dio.write_npz(cameras, "cameras", cameras_to_arrays(["left", "right"],
                                                            [scene.left, right]))
        out = tmp_path / label
        run_rectify(tmp_path / "left.tif", tmp_path / "right.tif", out, RectifyParams(),
                    sensor_left=cameras, sensor_right=cameras)
        run_sgm(out / "left_rect.tif", out / "right_rect.tif", out / "disp.tif",
                SgmParams(fill=False), rectify=out / "rectify.npz")
        run_dem(out / "dem.tif", DemParams(), disparity_path=out / "disp.tif",
                rectify_path=out / "rectify.npz")
        rmse[label] = local_dem_errors(out / "dem.tif", scene)["rmse_m"]
        summary = json.loads((out / "rectify.npz.json").read_text())["summary"]
        residuals[label] = (summary["rms_vertical_residual_before_px"],
                            summary["rms_vertical_residual_px"])
    assert residuals["off"][1] < residuals["off"][0]  # reported before / after
    assert rmse["off"] <= 1.5 * rmse["exact"], rmse


def test_swapped_models_are_refused_in_one_line():
    from demtool.errors import InputError
    from demtool.rectify.checks import check_left_right

    left, right = _rig()
    check_left_right(left, right, "l.tsai", "r.tsai")
    with pytest.raises(InputError, match="r.tsai: its camera stands 0.3 m to the left of "
                       "l.tsai's.*swapped"):
        check_left_right(right, left, "l.tsai", "r.tsai")
    # one camera above the other: the baseline runs across the rows, not refused
    above = dataclasses.replace(right, t=-right.R @ (left.center + [0, 0, 0.3]))
    check_left_right(left, above, "l.tsai", "r.tsai")


def test_rows_far_beyond_a_calibrations_error_are_refused():
    left, right = _rig()
    lower = dataclasses.replace(right, t=-right.R @ (right.center + [0, 0, -0.12]))
    pl, pr = _matches(left, lower, seed=5)  # the images of a rig 12 cm out of level
    with pytest.raises(ProcessingError, match=r"rows disagree by \d+\.\d px RMS under the "
                       "models, more than a calibration's error") as info:
        rectify_sensors(left, right, pl, pr, what="rig")
    assert "\n" not in str(info.value)
