"""Issue 46's sweep: inputs that do not belong together, values that cannot be right and
sizes beyond the machine, over the newer stages — each refused in one line naming the
input (exit 1 or 2, nothing written) or given a right result.  Small synthetic fixtures
(the fuse DEMs of tests.helpers.fuse); the map-projected and --dense cases live beside
their routes' fixtures (tests/cli/test_mapstereo.py, tests/cli/test_dem_dense.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from affine import Affine
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from tests.helpers.fuse import GSD, ORIGIN, moon_crs, write_dem


def invoke(*args):
    return CliRunner().invoke(cli, ["-q", *map(str, args)])


def refused(result, *words, code=1, out=None):
    """Exit ``code``, one ``Error`` line holding every word, and nothing else on the
    output (no warning before it at -q); no file at ``out``."""
    assert result.exit_code == code, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "Error" in lines[0], result.output
    for word in words:
        assert str(word) in lines[0], lines[0]
    if out is not None:
        assert not list(out.parent.glob(out.name + "*")), list(out.parent.iterdir())


# ---------------------------------------------------------------- fuse
@pytest.fixture()
def two_dems(tmp_path):
    paths = [tmp_path / "a.tif", tmp_path / "b.tif"]
    write_dem(paths[0], (0, 60, 0, 60), noise=0.05, seed=1)
    write_dem(paths[1], (5, 65, 5, 65), noise=0.05, seed=2, shift=(0.0, 0.0, 0.4))
    return paths


def test_fuse_refuses_image_frame_dems_of_different_targets(tmp_path):
    rng = np.random.default_rng(0)
    paths = []
    for name in ("view_00", "view_07"):
        paths.append(tmp_path / f"dem_{name}.tif")
        dio.write_raster(paths[-1], rng.normal(0, 1, (40, 40)), tags={"frame": f"image:{name}"})
    out = tmp_path / "fused.tif"
    refused(invoke("fuse", *paths, "--out", out), paths[1], "image:view_07", "image:view_00",
            out=out)


def test_fuse_refuses_a_dem_given_as_its_own_error_raster(two_dems, tmp_path):
    out = tmp_path / "fused.tif"
    refused(invoke("fuse", *two_dems, "--error", two_dems[0], "--error", two_dems[0],
                   "--out", out), two_dems[0], "is the DEM", "itself", out=out)


def test_fuse_sizes_the_grid_before_allocating(two_dems, tmp_path):
    """A --grid-like of 100 000² cells (a sparse GeoTIFF: no data written) and a union with
    a global mosaic are refused before any allocation, naming what made them."""
    import rasterio

    crs, _ = moon_crs()
    huge = tmp_path / "huge.tif"
    with rasterio.open(huge, "w", driver="GTiff", width=100_000, height=100_000, count=1,
                       dtype="float32", crs=crs, tiled=True, sparse_ok=True, nodata=np.nan,
                       transform=Affine(GSD, 0, ORIGIN[0], 0, -GSD, ORIGIN[1])):
        pass
    out = tmp_path / "fused.tif"
    refused(invoke("fuse", *two_dems, "--grid-like", huge, "--out", out),
            f"--grid-like {huge}", "100000 x 100000 cells", out=out)
    # a global mosaic: 3 x 2 cells covering the whole equirectangular Moon
    world = tmp_path / "world.tif"
    half = np.pi * 1737400.0
    dio.write_raster(world, np.zeros((2, 3)), crs=crs,
                     transform=Affine(2 * half / 3, 0, -half, 0, -half / 2, half / 2))
    refused(invoke("fuse", *two_dems, world, "--out", out), world, "union", out=out)


def test_fuse_names_the_dem_that_does_not_coregister_and_max_nmad_drops_it(two_dems,
                                                                            tmp_path):
    """A DEM in millimetres among good DEMs (N & K diverges): the error names it; with
    --max-nmad it is left out and the others are fused."""
    good = tmp_path / "c.tif"
    write_dem(good, (2, 62, 3, 63), noise=0.05, seed=3)
    bad = tmp_path / "millimetres.tif"
    info = dio.read_raster(two_dems[1])
    dio.write_raster(bad, info.data * 1000, transform=info.transform, crs=info.crs,
                     tags=info.tags)
    out = tmp_path / "fused.tif"
    dems = (two_dems[0], bad, two_dems[1], good)
    refused(invoke("fuse", *dems, "--out", out), f"{bad}:", "diverged", "--max-nmad",
            out=out)
    result = invoke("fuse", *dems, "--max-nmad", "1", "--out", out)
    assert result.exit_code == 0, result.output
    assert result.output.count("left out") == 1 and str(bad) in result.output
    summary = json.loads(out.with_name("fused.tif.json").read_text())["summary"]
    assert [d["used"] for d in summary["dems"]] == [True, False, True, True]


def test_fuse_with_a_coarse_dem_first_coregisters_the_fine_ones(tmp_path):
    """A DEM of 8× the spacing first sets the fused grid; the fine DEMs (one shifted by
    1.5 cells of 2 m = 3 m east) still co-register: no "barely overlap", shift found."""
    from tests.helpers.fuse import truth_heights

    crs, body = moon_crs()
    coarse = tmp_path / "coarse.tif"
    rows, cols = np.mgrid[0:12, 0:12].astype(np.float64)
    heights = truth_heights(rows * 8 + 3.5, cols * 8 + 3.5)
    dio.write_raster(coarse, heights, crs=crs, tags=body.tags(),
                     transform=Affine(8 * GSD, 0, ORIGIN[0], 0, -8 * GSD, ORIGIN[1]))
    fine, shifted = tmp_path / "fine.tif", tmp_path / "shifted.tif"
    write_dem(fine, (0, 96, 0, 96), noise=0.02, seed=1)
    write_dem(shifted, (0, 96, 0, 96), noise=0.02, seed=2, shift=(1.5, 0.0, 0.0))
    out = tmp_path / "fused.tif"
    result = invoke("fuse", coarse, fine, shifted, "--reference", fine, "--out", out)
    assert result.exit_code == 0, result.output
    dems = json.loads(out.with_name("fused.tif.json").read_text())["summary"]["dems"]
    dx_m = dems[2]["alignment"]["shift"]["dx_px"] * 8 * GSD  # fused cells of 16 m
    assert abs(dx_m - (-1.5 * GSD)) < 0.5, dems[2]["alignment"]


# ---------------------------------------------------------------- values that cannot be right
def test_bundle_refuses_a_focal_length_no_pinhole_camera_has(tmp_path):
    """--focal-mm 14 --pixel-mm 7 (µm typed as mm): 2 px, a 177° field of view on 96 px
    images; refused before any matching, naming both options and the value."""
    paths = []
    for name in ("a", "b"):
        paths.append(tmp_path / f"{name}.tif")
        dio.write_raster(paths[-1], np.random.default_rng(len(paths)).random((96, 96)))
    out = tmp_path / "bundle.npz"
    refused(invoke("bundle", *paths, "--focal-mm", "14", "--pixel-mm", "7", "--out", out),
            "--focal-mm 14 / --pixel-mm 7", "2 px", "field of view", out=out)


@pytest.mark.parametrize("kind, key, index, value, words", [
    ("cameras", "K", (1, 0, 0), np.nan, ["'K' of camera view_01 holds nan"]),
    ("cameras", "t", (0, 2), np.inf, ["'t' of camera view_00 holds inf"]),
    ("cameras", "K", (0, 1, 1), -800.0, ["'K' of camera view_00", "focal length -800"]),
])
def test_camera_files_with_values_no_camera_has_are_refused(tmp_path, kind, key, index,
                                                            value, words):
    """A NaN or infinite K, R or t, or a focal length ≤ 0, in cameras.npz: refused on
    reading, naming the file, the key, the camera and the value (a NaN K went on)."""
    from demtool.errors import InputError

    K = np.array([[800.0, 0, 48], [0, 800.0, 48], [0, 0, 1]])
    arrays = {"names": np.array(["view_00", "view_01"]), "K": np.stack([K, K]),
              "R": np.stack([np.eye(3)] * 2), "t": np.zeros((2, 3)),
              "width": np.array([96, 96]), "height": np.array([96, 96])}
    good = tmp_path / "good.npz"
    dio.write_npz(good, kind, arrays)
    arrays[key][index] = value
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays, kind=np.asarray(kind), format_version=np.asarray(3))
    with pytest.raises(InputError) as caught:
        dio.read_npz(path, kind)
    for word in [str(path), *words]:
        assert word in str(caught.value), caught.value
    assert dio.read_npz(good, kind)["K"].shape == (2, 3, 3)


# ---------------------------------------------------------------- one surface across stages
def test_camera_and_pairs_see_the_overlap_on_the_chains_surface(tmp_path):
    """Issue 46: camera intersected the model's ellipsoid while synth, mapproject and dem
    use the body's reference sphere.  Two narrow frame cameras on Mars looking at one
    point at 60°N on the sphere from 30° east and west (the ellipsoid lies 15 km lower
    there): their footprints overlap on the sphere, as the chain sees them."""
    from demtool.maps import body_from_radii, enu_frame, lonlat_height_to_xyz
    from tests.helpers.camera_isd import frame_isd, look_at_rotation, write_isd

    a, c = 3396190.0, 3376200.0
    radius = body_from_radii(a, a, c).radius
    east, north, up = enu_frame(20.0, 60.0)
    target = lonlat_height_to_xyz(20.0, 60.0, 0.0, radii=radius)
    paths = []
    for name, side in (("west", -1.0), ("east", 1.0)):
        position = target + 300e3 * up + side * 300e3 * np.tan(np.radians(30)) * east
        isd = frame_isd(position, look_at_rotation(position, target, north), focal_mm=500.0,
                        pitch_mm=0.01, lines=300, samples=300, name=name)
        isd["radii"] = {"semimajor": a, "semiminor": c, "unit": "m"}
        paths.append(write_isd(tmp_path / f"{name}.json", isd))
    result = invoke("camera", *paths, "--json")
    assert result.exit_code == 0, result.output
    pair = json.loads(result.output)["pairs"][0]
    assert pair["overlap_fraction_first"] > 0.9, pair
    assert pair["convergence_deg"] == pytest.approx(60.0, abs=0.5)


def test_an_unaligned_bundle_is_measured_on_its_tie_points(tmp_path):
    """Issue 46: an unaligned bundle.npz (COLMAP's arbitrary frame) gave pairs no pair: the
    local frame's ground Z = 0 means nothing there.  Its cameras are measured on the plane
    of its tie points: the same block moved by a similarity (rotation, scale 0.01,
    offset) has the overlap and convergence of the metric one."""
    from scipy.spatial.transform import Rotation

    from demtool.bundle import BundleResult
    from demtool.sensors import PinholeCamera
    from tests.cli.test_dem import bundle_points, write_bundle
    from tests.helpers.dem import BASELINE, nadir_camera

    points = bundle_points(80)
    metric = write_bundle(tmp_path / "metric.npz", points, nadir_camera(), aligned=True)
    rotation = Rotation.from_euler("xyz", [40, -70, 15], degrees=True).as_matrix()
    scale, offset = 0.01, np.array([3.0, -2.0, 7.0])
    moved_cameras = []
    for camera in (nadir_camera(), nadir_camera(BASELINE)):
        # X' = s Q X + o  →  x_cam ∝ R Qᵀ X' + s t − R Qᵀ o  (the same image, scaled frame)
        R = camera.R @ rotation.T
        moved_cameras.append(PinholeCamera(K=camera.K, R=R, t=scale * camera.t - R @ offset,
                                           width=camera.width, height=camera.height))
    moved = BundleResult(points=scale * points @ rotation.T + offset,
                         colors=np.zeros(len(points)), track_length=np.full(len(points), 2),
                         reprojection_error=np.full(len(points), 0.2),
                         image_names=np.array(["view_00", "view_01"]), cameras=moved_cameras,
                         distortion=np.zeros((2, 2)), target_index=0, aligned=False)
    unaligned = dio.write_npz(tmp_path / "unaligned.npz", "bundle", moved.to_arrays())
    pairs = []
    for path in (metric, unaligned):
        result = invoke("camera", path, "--json")
        assert result.exit_code == 0, result.output
        pairs.append(json.loads(result.output)["pairs"][0])
    assert pairs[1]["overlap_fraction_first"] == pytest.approx(
        pairs[0]["overlap_fraction_first"], abs=0.05)
    assert pairs[1]["convergence_deg"] == pytest.approx(pairs[0]["convergence_deg"], abs=0.1)
