"""demtool.dem.dense: a BAM DEM densified by a pair of the block, against synthetic truth.

The paraboloid of :mod:`tests.helpers.dem` seen by two parallel nadir cameras 12 m apart
at 1000 m; the pair's disparity is exact (the true geometry), the tie points are a sparse
sample of the true surface.  The densified DEM must be measured where the pair sees and
at least as accurate as the sparse BAM DEM everywhere.
"""

from __future__ import annotations

import numpy as np
import pytest

from demtool.dem import dem_from_points
from demtool.dem.dense import (
    MAX_MEDIAN_GAP_PX,
    DensePair,
    Samples,
    dem_from_points_dense,
    merge_samples,
)
from demtool.errors import InputError, ProcessingError
from demtool.sensors.pinhole import PinholeCamera
from tests.helpers.dem import (
    ALTITUDE,
    BASELINE,
    RECTIFY,
    nadir_camera,
    surface,
    synthetic_disparity,
    truth_grid,
)

#: inside the pair's coverage in view_00 (right of the 24 px strip view_01 does not see):
#: exact data give mm there; the ties alone in the strip are off by their half-pixel
#: rounding on the slope, the coverage's edge cells by the resampling's extrapolation
SEEN = (slice(4, -4), slice(28, -4))


def tie_points(n: int = 60, seed: int = 4) -> np.ndarray:
    """Sparse bundle points on the true surface, inside the target's footprint."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-22, 22, (n, 2))
    return np.column_stack([xy, surface(xy[:, 0], xy[:, 1])])


def the_pair(disparity: np.ndarray | None = None) -> DensePair:
    if disparity is None:
        disparity = synthetic_disparity(nadir_camera(), nadir_camera(BASELINE))
    return DensePair(disparity, RECTIFY, RECTIFY, "view_00", "view_01", "disparity.tif")


def scaled(camera: PinholeCamera, scale: float) -> PinholeCamera:
    """The camera of a model that is the world scaled by ``scale`` (an unaligned bundle)."""
    return PinholeCamera(K=camera.K, R=camera.R, t=camera.t * scale, width=camera.width,
                         height=camera.height)


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def test_metric_bundle_densified_is_measured_and_more_accurate():
    cameras = {"view_00": nadir_camera(), "view_01": nadir_camera(BASELINE)}
    points = tie_points()
    sparse = dem_from_points(points, cameras["view_00"], aligned=True)
    dense = dem_from_points_dense(points, cameras, "view_00", [the_pair()], aligned=True)
    truth = truth_grid(cameras["view_00"])
    assert sparse.report["measured_fraction"] < 0.01
    # The right camera sees the scene shifted by 24 px: 3/4 of the target is measured.
    assert dense.report["measured_fraction"] > 0.7
    assert dense.report["cells_dense_only"] > 100 * dense.report["cells_ties"]
    inner = (slice(4, -4), slice(4, -4))
    error_sparse = rms((sparse.dem - truth)[inner])
    error_dense = rms((dense.dem - truth)[inner])
    assert error_dense <= error_sparse
    error = np.abs(dense.dem - truth)
    measured = ~dense.interpolated
    assert error[SEEN][measured[SEEN]].max() < 0.005
    assert error[measured].max() < 0.05
    assert dense.report["tie_minus_dense_median_m"] == pytest.approx(0.0, abs=0.005)
    assert dense.report["tie_outliers"] == 0 and dense.report["dense_outliers"] < 50


def test_unaligned_bundle_heights_share_the_tie_points_eq2_datum():
    """An unaligned bundle (the world scaled by 0.01): dense heights by eq. 2 with the tie
    points' mean depth, so both sources give one height per model depth."""
    scale, distance = 0.01, 1000.0
    world = {"view_00": nadir_camera(), "view_01": nadir_camera(BASELINE)}
    cameras = {name: scaled(camera, scale) for name, camera in world.items()}
    points = tie_points()
    dense = dem_from_points_dense(points * scale, cameras, "view_00", [the_pair()],
                                  aligned=False, distance_m=distance)
    mean_depth = float(np.mean(ALTITUDE - points[:, 2]))  # the tie points' mean depth
    expected = -((ALTITUDE - truth_grid(world["view_00"])) / mean_depth - 1.0) * distance
    measured = ~dense.interpolated
    assert measured.mean() > 0.7
    assert np.abs(dense.dem - expected)[SEEN][measured[SEEN]].max() < 0.005
    assert dense.report["height_scale"].startswith("eq. 2")


def test_pair_without_the_target_is_projected_into_it():
    """The pair (view_00, view_01) densifies the DEM of another view of the block."""
    cameras = {"view_00": nadir_camera(), "view_01": nadir_camera(BASELINE),
               "view_02": nadir_camera(0.5 * BASELINE)}
    dense = dem_from_points_dense(tie_points(), cameras, "view_02", [the_pair()],
                                  aligned=True)
    measured = ~dense.interpolated
    assert measured.mean() > 0.6
    truth = truth_grid(cameras["view_02"])  # view_02 is 12 px right of view_00
    seen = (SEEN[0], slice(16, -4))
    error = (dense.dem - truth)[seen][measured[seen]]
    assert rms(error) < 0.002 and np.abs(error).max() < 0.01


def test_merge_drops_a_disagreeing_tie_and_averages_an_agreeing_one():
    """A plane 0.1 m/px in x measured densely (1 cm noise) and by 25 ties on a 4 px lattice
    (2 cm noise) in the left 20 columns; one more tie, 5 m off, among them.  Where the
    dense source is absent (columns 20 … 29) the ties measure alone."""
    rng = np.random.default_rng(0)
    rows, cols = np.mgrid[:20, :20]
    dense_pixels = np.column_stack([cols.ravel(), rows.ravel()]).astype(float) + 0.25
    dense_heights = 0.1 * dense_pixels[:, 0] + rng.normal(0, 0.01, 400)
    lattice = np.mgrid[1:20:4, 1:30:4].reshape(2, -1).T[:, ::-1].astype(float) + 0.3
    tie_pixels = np.vstack([lattice, [[12.0, 9.0]]])
    tie_heights = 0.1 * tie_pixels[:, 0] + rng.normal(0, 0.02, len(tie_pixels))
    tie_heights[-1] += 5.0
    measured, report = merge_samples(Samples(tie_pixels, tie_heights),
                                     Samples(dense_pixels, dense_heights), (20, 30))
    assert report["tie_outliers"] == 1 and report["cells_ties"] == len(lattice)
    assert measured[9, 12] == pytest.approx(1.2, abs=0.05)  # the dense surface, not the tie
    # a surviving tie, moved to its cell's centre along the dense surface (−0.03 m from
    # x = 5.3 to 5), is averaged with the dense height there
    index = int(np.flatnonzero((tie_pixels == [5.3, 5.3]).all(axis=1))[0])
    dense_only, _ = merge_samples(Samples(tie_pixels[:0], tie_heights[:0]),
                                  Samples(dense_pixels, dense_heights), (20, 30))
    assert measured[5, 5] == pytest.approx(
        0.5 * (tie_heights[index] - 0.03 + dense_only[5, 5]), abs=0.005)
    # right of the dense samples' reach (column 20) only the 3 × 5 lattice ties measure
    assert np.isfinite(measured[:, 21:]).sum() == 15
    assert report["cells_ties"] - report["cells_both"] == 15
    assert report["cells_dense_only"] == report["cells_dense"] - report["cells_both"]
    assert report["tie_minus_dense_median_m"] == pytest.approx(0.0, abs=0.02)


def test_pair_of_another_block_is_refused():
    """A bundle whose view_01 points 0.3° off (another block's adjustment): the pair's rows
    are 10 px off its epipolar lines, so through these cameras its rays miss each other."""
    right = nadir_camera(BASELINE)
    angle = np.radians(0.3)
    pitch = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)],
                      [0.0, np.sin(angle), np.cos(angle)]])
    rotation = pitch @ right.R
    other = PinholeCamera(K=right.K, R=rotation, t=-rotation @ right.center,
                          width=right.width, height=right.height)
    cameras = {"view_00": nadir_camera(), "view_01": other}
    with pytest.raises(InputError, match="miss each other"):
        dem_from_points_dense(tie_points(), cameras, "view_00", [the_pair()], aligned=True)
    assert MAX_MEDIAN_GAP_PX >= 1.0
    missing = DensePair(the_pair().disparity, RECTIFY, RECTIFY, "view_00", "view_07", "d.tif")
    with pytest.raises(InputError, match="view_07 is not registered"):
        dem_from_points_dense(tie_points(), cameras, "view_00", [missing], aligned=True)


def test_pair_that_misses_the_target_is_refused():
    far = nadir_camera(5000.0)
    cameras = {"view_00": nadir_camera(), "view_01": nadir_camera(BASELINE), "view_09": far}
    ties = tie_points() + np.array([5000.0, 0.0, 0.0])
    with pytest.raises(ProcessingError, match="no overlap with the target view_09"):
        dem_from_points_dense(ties, cameras, "view_09", [the_pair()], aligned=True)
