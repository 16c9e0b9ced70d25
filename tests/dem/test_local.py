"""The local-frame DEM core (demtool.dem.local): axes, gridding, occlusion, PLY."""

from __future__ import annotations

import numpy as np
import pytest

from demtool.dem.local import (
    cells_behind_cameras,
    dem_on_local_grid,
    footprint_gsd,
    local_frame,
)
from demtool.errors import ProcessingError
from demtool.sensors.pinhole import look_at


def test_local_frame_axes_right_handed_for_any_up():
    for up in [(0, 0, 1), (0, 0, -1), (1, 0, 0), (0.2, -0.3, 0.9)]:
        frame = local_frame(up)
        axes = frame.axes
        np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(axes) == pytest.approx(1.0)
        np.testing.assert_allclose(frame.up, np.asarray(up) / np.linalg.norm(up))
    # z-down frame: x stays the frame's X, y = up × x = −Y (the Z-up frame's Y)
    np.testing.assert_allclose(local_frame((0, 0, -1)).axes[:2], [[1, 0, 0], [0, -1, 0]])
    with pytest.raises(ValueError):
        local_frame((0, 0, 0))


def test_heights_along_up_recover_a_tilted_plane():
    rng = np.random.default_rng(1)
    up = np.array([0.1, -0.2, 1.0])
    frame = local_frame(up)
    xy = rng.uniform(-2, 2, (20000, 2))
    h = 0.5 + 0.1 * xy[:, 0] - 0.05 * xy[:, 1]
    xyz = frame.to_frame(np.column_stack([xy, h]))
    result = dem_on_local_grid(xyz, np.zeros(len(xyz)), frame, gsd_m=0.05)
    rows, cols = np.nonzero(np.isfinite(result.dem))
    t = result.transform
    x = t.c + (cols + 0.5) * t.a
    y = t.f + (rows + 0.5) * t.e
    truth = 0.5 + 0.1 * x - 0.05 * y
    assert np.sqrt(np.mean((result.dem[rows, cols] - truth) ** 2)) < 0.01
    assert result.report["measured_cells"] > 0.8 * rows.size
    assert t.a == pytest.approx(0.05) and t.e == pytest.approx(-0.05)


def test_far_mismatches_do_not_stretch_the_grid():
    frame = local_frame()
    rng = np.random.default_rng(2)
    xyz = np.column_stack([rng.uniform(0, 1, (5000, 2)), np.zeros(5000)])
    xyz[:5] = [1e4, 1e4, 3.0]  # five points "at infinity"
    result = dem_on_local_grid(xyz, np.zeros(len(xyz)), frame, gsd_m=0.05)
    assert max(result.dem.shape) < 30
    assert result.report["points_outside_extent"] >= 5


def test_too_few_points_and_huge_grids_are_refused():
    frame = local_frame()
    with pytest.raises(ProcessingError, match="only 2"):
        dem_on_local_grid(np.zeros((2, 3)), np.zeros(2), frame, gsd_m=0.1)
    xyz = np.column_stack([np.linspace(0, 1000, 1000), np.linspace(0, 1000, 1000),
                           np.zeros(1000)])
    with pytest.raises(ProcessingError, match="coarser --gsd"):
        dem_on_local_grid(xyz, np.zeros(1000), frame, gsd_m=0.01)


def test_fill_stays_where_both_cameras_see_and_nothing_behind_them():
    # two cameras 1 m above flat ground looking forward and down; points on the ground
    # seen by both, with a hole; plus the frame's grid behind the cameras must stay empty
    left = look_at((-0.15, 0, 1), (-0.15, 3, 0), up=(0, 0, 1), focal_px=200, width=160,
                   height=120)
    right = look_at((0.15, 0, 1), (0.15, 3, 0), up=(0, 0, 1), focal_px=200, width=160,
                    height=120)
    rows, cols = np.mgrid[0:120:2, 0:160:2]
    pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float)
    rays = left.rays(pixels)
    s = -left.center[2] / rays[:, 2]
    ground = left.center + s[:, None] * rays
    ground = ground[(s > 0) & (np.hypot(ground[:, 0], ground[:, 1] - 2.5) > 0.3)]
    frame = local_frame()
    result = dem_on_local_grid(ground, np.zeros(len(ground)), frame, gsd_m=0.03,
                               left=left, right=right)
    assert result.report["filled_cells"] > 0
    valid = np.isfinite(result.dem)
    np.testing.assert_allclose(result.dem[valid], 0.0, atol=1e-6)
    assert cells_behind_cameras(result.dem, result.transform, frame, (left, right)) == 0
    gsd = footprint_gsd(ground, left.center, frame, 1 / 200)
    assert 0.005 < gsd < 0.05


def test_write_ply_round_trip(tmp_path):
    from demtool import io as dio

    xyz = np.array([[0.0, 1.0, 2.0], [3.5, -1.25, 1e3]])
    dio.write_ply(tmp_path / "p.ply", xyz, {"ray_gap": np.array([0.1, 0.2])},
                  comments=["frame test"])
    raw = (tmp_path / "p.ply").read_bytes()
    header, body = raw.split(b"end_header\n", 1)
    assert b"element vertex 2" in header and b"comment frame test" in header
    record = np.frombuffer(body, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                        ("ray_gap", "<f4")])
    np.testing.assert_array_equal(np.column_stack([record["x"], record["y"], record["z"]]),
                                  xyz)
    np.testing.assert_allclose(record["ray_gap"], [0.1, 0.2], rtol=1e-6)


def _ground_under_cameras(z_down=False):
    """Points on a bumpy ground 1-5 m ahead of two cameras 0.9 m above it."""
    rng = np.random.default_rng(5)
    xy = np.column_stack([rng.uniform(-1.5, 1.5, 5000), rng.uniform(1, 5, 5000)])
    z = 0.05 * np.sin(3 * xy[:, 0]) + rng.normal(0, 0.01, 5000)
    points = np.column_stack([xy, z])
    centers = np.array([[-0.15, 0, 0.9], [0.15, 0, 0.9]])
    if z_down:  # the same scene in a frame with Z down (180° about X)
        flip = np.diag([1.0, -1.0, -1.0])
        points, centers = points @ flip, centers @ flip
    return points, centers


def test_up_is_inferred_from_the_ground_on_the_cameras_side():
    from demtool.dem.local import check_up, fit_ground_normal, infer_up

    for z_down, expected in ((False, (0, 0, 1)), (True, (0, 0, -1))):
        points, centers = _ground_under_cameras(z_down)
        up, source = infer_up(points, centers)
        np.testing.assert_allclose(up, expected)
        assert "inferred" in source
        assert check_up(up, points, centers, "--up") == pytest.approx(0.9, abs=0.02)
        normal, rms = fit_ground_normal(points, centers)
        assert np.degrees(np.arccos(abs(normal @ up))) < 2.0 and rms < 0.05
    # a tilted ground (20°) far from any axis keeps its own normal
    points, centers = _ground_under_cameras()
    tilt = np.radians(20)
    turn = np.array([[1, 0, 0], [0, np.cos(tilt), -np.sin(tilt)],
                     [0, np.sin(tilt), np.cos(tilt)]])
    up, source = infer_up(points @ turn.T, centers @ turn.T)
    np.testing.assert_allclose(up, turn @ [0, 0, 1], atol=0.02)
    assert "normal" in source


def test_an_up_that_puts_the_cameras_under_the_ground_is_refused():
    from demtool.dem.local import check_up

    points, centers = _ground_under_cameras(z_down=True)
    with pytest.raises(ProcessingError, match=r"--up 0,0,1 puts the cameras 0.9\d* m below")\
            as info:
        check_up(np.array([0, 0, 1.0]), points, centers, "--up")
    assert "0,0,-1" in str(info.value) and "\n" not in str(info.value)


def test_points_far_beyond_the_matches_ranges_are_outliers():
    from demtool.dem.local import beyond_matches

    rng = np.random.default_rng(6)
    match_ranges = rng.uniform(1.0, 5.0, 300)
    xyz = np.array([[0, 3.0, 0], [0, 9.0, 0], [0, 11.0, 0], [0, 0.45, 0], [0, 1600.0, 0]])
    np.testing.assert_array_equal(beyond_matches(xyz, np.zeros(3), match_ranges),
                                  [False, False, True, True, True])
    assert not beyond_matches(xyz, np.zeros(3), np.zeros(0)).any()


def test_the_grid_covers_the_bulk_of_a_perspective_view():
    frame = local_frame()
    rng = np.random.default_rng(7)
    near = np.column_stack([rng.uniform(-1, 1, 20000), rng.uniform(1, 3, 20000),
                            np.zeros(20000)])
    far = np.column_stack([rng.uniform(-15, 15, 400), rng.uniform(10, 30, 400),
                           np.zeros(400)])  # 2 % of the points, spread over 600 m²
    xyz = np.concatenate([near, far])
    result = dem_on_local_grid(xyz, np.zeros(len(xyz)), frame, gsd_m=0.05,
                               center=np.array([0.0, 0.0, 1.0]))
    assert result.report["points_beyond_bulk"] >= 390
    assert max(result.dem.shape) <= 50  # 2 m x 2 m at 5 cm, not 30 m x 30 m


def test_points_seen_along_the_baseline_converge_too_little():
    from demtool.dem.local import weak_convergence

    centers = np.array([[-0.15, 0, 1.0], [0.15, 0, 1.0]])
    ahead = np.array([[0.0, 3.0, 0.0]])  # 5.7° between the rays: 16 px at f = 160
    along = np.array([[-5.0, 0.1, 0.9]])  # beside the baseline: 0.07° apart
    assert not weak_convergence(ahead, centers, 160.0)[0]
    assert weak_convergence(along, centers, 160.0)[0]


def test_images_upside_down_along_up_are_refused():
    from demtool.dem.local import check_upright

    left = look_at((-0.15, 0, 1), (-0.15, 3, 0), up=(0, 0, 1), focal_px=200, width=160,
                   height=120)
    right = look_at((0.15, 0, 1), (0.15, 3, 0), up=(0, 0, 1), focal_px=200, width=160,
                    height=120)
    assert check_upright(np.array([0, 0, 1.0]), (left, right), "r.npz") > 0.3
    with pytest.raises(ProcessingError, match=r"r.npz: the cameras' images would stand "
                       r"upside down along up 0,0,-1 \(their top 1\d\d° from it\)") as info:
        check_upright(np.array([0, 0, -1.0]), (left, right), "r.npz")
    assert "\n" not in str(info.value)
