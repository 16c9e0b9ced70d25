"""demtool.io: rasters, images, NPZ schemas, JSON, atomic writes and transactions."""

import json
import os

import numpy as np
import pytest
import rasterio
from affine import Affine

from demtool import io as dio
from demtool.errors import InputError


def test_raster_round_trip_keeps_values_nan_transform_and_tags(tmp_path):
    data = np.arange(12, dtype=np.float32).reshape(3, 4)
    data[1, 2] = np.nan
    transform = dio.image_frame_transform(0.5)
    path = dio.write_raster(tmp_path / "a.tif", data, transform=transform,
                            tags={"frame": "image:view_00", "params": {"p1": 8}})
    raster = dio.read_raster(path)
    assert raster.data.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(raster.data), np.isnan(data))
    np.testing.assert_allclose(raster.data[~np.isnan(data)], data[~np.isnan(data)])
    assert raster.transform == transform
    assert raster.spacing == (0.5, 0.5)
    assert raster.crs is None
    assert raster.tags["frame"] == "image:view_00"
    assert raster.tag_json("params") == {"p1": 8}
    with rasterio.open(path) as ds:
        assert ds.dtypes[0] == "float32"
        assert np.isnan(ds.nodata)


def test_raster_with_crs_and_bands(tmp_path):
    data = np.random.default_rng(0).random((2, 8, 9)).astype(np.float32)
    path = dio.write_raster(tmp_path / "b.tif", data, transform=Affine(2, 0, 500000, 0, -2, 0),
                            crs="EPSG:32633", band_names=["height", "mask"])
    second = dio.read_raster(path, band=2)
    np.testing.assert_allclose(second.data, data[1])
    assert second.crs.to_epsg() == 32633
    with pytest.raises(InputError, match="band 3"):
        dio.read_raster(path, band=3)


def test_missing_corrupt_and_all_nan_rasters_are_named(tmp_path):
    with pytest.raises(InputError, match=r"nope\.tif: DEM not found"):
        dio.read_raster(tmp_path / "nope.tif", what="DEM")
    corrupt = tmp_path / "corrupt.tif"
    corrupt.write_bytes(b"II*\x00garbage" * 10)
    with pytest.raises(InputError, match=r"corrupt\.tif: cannot read"):
        dio.read_raster(corrupt)
    empty = dio.write_raster(tmp_path / "nan.tif", np.full((4, 4), np.nan))
    with pytest.raises(InputError, match="no valid"):
        dio.read_raster(empty)
    assert np.isnan(dio.read_raster(empty, allow_all_nan=True).data).all()


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_read_image_converts_colour_png_to_grey(tmp_path):
    rgb = np.zeros((3, 5, 6), dtype=np.uint8)
    rgb[0] = 100
    rgb[1] = 200
    rgb[2] = 50
    path = tmp_path / "c.png"
    with rasterio.open(path, "w", driver="PNG", width=6, height=5, count=3, dtype="uint8") as ds:
        ds.write(rgb)
    image = dio.read_image(path)
    assert image.data.shape == (5, 6)
    np.testing.assert_allclose(image.data, 0.299 * 100 + 0.587 * 200 + 0.114 * 50, rtol=1e-6)
    assert image.transform == dio.image_frame_transform(1.0)


def _rect_arrays(n=5):
    rng = np.random.default_rng(1)
    pts = rng.random((n, 2)) * 100
    return {
        "H_left": np.eye(3), "H_right": np.eye(3), "F": np.ones((3, 3)),
        "size_left": np.array([100, 80]), "size_right": np.array([100, 80]),
        "size_rect": np.array([110, 90]),
        "points_left": pts, "points_right": pts - [3, 0],
        "points_left_rect": pts, "points_right_rect": pts - [3, 0],
        "disparity_range": np.array([0.0, 8.0]),
        "left_name": np.array("view_00"), "right_name": np.array("view_01"),
    }


def test_npz_round_trip_and_schema_errors(tmp_path):
    path = dio.write_npz(tmp_path / "rectify.npz", "rectification", _rect_arrays())
    content = dio.read_npz(path, "rectification")
    assert str(content["left_name"]) == "view_00"
    assert int(content["format_version"]) == dio.NPZ_FORMAT_VERSION
    with pytest.raises(InputError, match=r"rectify\.npz: is a rectification file, expected a bun"):
        dio.read_npz(path, "bundle")
    arrays = _rect_arrays()
    del arrays["F"]
    with pytest.raises(InputError, match="lacks the key 'F'"):
        dio.write_npz(tmp_path / "x.npz", "rectification", arrays)
    assert not (tmp_path / "x.npz").exists()
    arrays = _rect_arrays()
    arrays["points_right"] = arrays["points_right"][:3]
    with pytest.raises(InputError, match="points_right"):
        dio.write_npz(tmp_path / "y.npz", "rectification", arrays)
    arrays = _rect_arrays()
    arrays["H_left"] = np.eye(4)
    with pytest.raises(InputError, match=r"'H_left'.*shape \(4, 4\)"):
        dio.write_npz(tmp_path / "z.npz", "rectification", arrays)


def test_npz_missing_key_in_file_on_disk_is_named(tmp_path):
    arrays = {k: v for k, v in _rect_arrays().items() if k != "H_right"}
    path = tmp_path / "old.npz"
    np.savez(path, kind=np.array("rectification"), format_version=np.array(1), **arrays)
    with pytest.raises(InputError, match=r"old\.npz: rectification file lacks the key 'H_right'"):
        dio.read_npz(path, "rectification")
    plain = tmp_path / "plain.npz"
    np.savez(plain, a=np.zeros(3))
    with pytest.raises(InputError, match="not a demtool NPZ"):
        dio.read_npz(plain, "cameras")
    garbage = tmp_path / "garbage.npz"
    garbage.write_text("not a zip")
    with pytest.raises(InputError, match="not a readable NPZ"):
        dio.read_npz(garbage, "cameras")


def test_json_is_strict_and_atomic(tmp_path):
    path = dio.write_json(tmp_path / "r.json", {"a": np.float32(1.5), "b": np.arange(3),
                                                 "c": float("nan")})
    assert json.loads(path.read_text()) == {"a": 1.5, "b": [0, 1, 2], "c": None}
    bad = tmp_path / "bad.json"
    bad.write_text("{oops")
    with pytest.raises(InputError, match=r"bad\.json: .* not valid JSON"):
        dio.read_json(bad)


def test_transaction_leaves_nothing_on_failure(tmp_path):
    with pytest.raises(RuntimeError):
        with dio.output_transaction():
            dio.write_raster(tmp_path / "one.tif", np.zeros((4, 4)))
            dio.write_json(tmp_path / "two.json", {"x": 1})
            assert not (tmp_path / "one.tif").exists()  # deferred until success
            raise RuntimeError("stage failed half way")
    assert os.listdir(tmp_path) == []


def test_transaction_commits_all_outputs(tmp_path):
    with dio.output_transaction():
        dio.write_raster(tmp_path / "one.tif", np.zeros((4, 4)))
        dio.write_json(tmp_path / "two.json", {"x": 1})
    assert sorted(os.listdir(tmp_path)) == ["one.tif", "two.json"]


def test_atomic_write_replaces_existing_file_only_on_success(tmp_path):
    target = tmp_path / "keep.json"
    dio.write_json(target, {"v": 1})
    with pytest.raises(TypeError):
        dio.write_json(target, {"v": object()})
    assert json.loads(target.read_text()) == {"v": 1}
    assert os.listdir(tmp_path) == ["keep.json"]


def test_outputs_get_the_usual_file_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        path = dio.write_json(tmp_path / "perm.json", {"a": 1})
    finally:
        os.umask(umask)
    assert (path.stat().st_mode & 0o777) == 0o644


def _scaled_int16_dem(path, driver="GTiff"):
    """A LOLA-style DEM: int16 half-metres (scale 0.5) about an offset, with nodata."""
    stored = np.array([[-17269, 0, 21255], [-32768, 100, -1]], dtype=np.int16)
    with rasterio.open(path, "w", driver=driver, width=3, height=2, count=1, dtype="int16",
                       nodata=-32768, transform=Affine(118.0, 0, 0, 0, -118.0, 0),
                       crs="EPSG:4326" if driver == "GTiff" else None) as ds:
        ds.scales = (0.5,)  # before the data: the ISIS3 driver writes its label early
        ds.offsets = (-2.0,)
        ds.write(stored, 1)
    return stored


def test_scaled_int16_dem_reads_in_the_units_it_states(tmp_path):
    path = tmp_path / "lola.tif"
    stored = _scaled_int16_dem(path)
    dem = dio.read_raster(path, what="DEM")
    assert dem.data.dtype == np.float32
    expected = stored.astype(np.float64) * 0.5 - 2.0
    assert np.isnan(dem.data[1, 0])  # nodata is compared before scaling
    valid = stored != -32768
    np.testing.assert_array_equal(dem.data[valid], expected[valid].astype(np.float32))
    assert dem.data[0, 0] == -8636.5 and dem.data[0, 2] == 10625.5
    # The same through read_image (the DN of a scaled image are its physical values).
    np.testing.assert_array_equal(dio.read_image(path).data[valid], expected[valid])


def test_isis3_cube_base_and_multiplier_and_special_pixels(tmp_path):
    """ISIS3's Base/Multiplier are GDAL's offset/scale; its NULL pixel is the mask."""
    path = tmp_path / "dem.cub"
    stored = _scaled_int16_dem(path, driver="ISIS3")
    text = path.read_bytes()[:4096].decode("ascii", "replace")
    assert "Base" in text and "Multiplier" in text  # really stored as ISIS does
    dem = dio.read_raster(path, what="DEM")
    valid = stored != -32768
    np.testing.assert_array_equal(dem.data[valid], (stored[valid] * 0.5 - 2.0).astype(np.float32))
    assert np.isnan(dem.data[~valid]).all()


def test_infinities_and_float32_overflow_read_as_nan(tmp_path):
    data = np.array([[1.0, np.inf, -np.inf], [1e300, 2.5, np.nan]], dtype=np.float64)
    path = tmp_path / "inf.tif"
    with rasterio.open(path, "w", driver="GTiff", width=3, height=2, count=1,
                       dtype="float64", transform=Affine(2, 0, 0, 0, -2, 0)) as ds:
        ds.write(data, 1)
    raster = dio.read_raster(path)
    np.testing.assert_array_equal(np.isfinite(raster.data),
                                  [[True, False, False], [False, True, False]])
    assert raster.data[0, 0] == 1.0 and raster.data[1, 1] == 2.5
    # A raster whose only "values" are infinite has no valid pixel.
    path2 = tmp_path / "all_inf.tif"
    dio.write_raster(path2, np.full((2, 2), np.inf))
    with pytest.raises(InputError, match=r"all_inf\.tif: raster contains no valid"):
        dio.read_raster(path2)


def test_isis3_saturation_special_pixels_are_nodata(tmp_path):
    """LRS/LIS/HIS/HRS (-32767 … -32764 in SignedWord) are masked like NULL (-32768)."""
    path = tmp_path / "special.cub"
    with rasterio.open(path, "w", driver="ISIS3", width=3, height=2, count=1, dtype="int16",
                       nodata=-32768, transform=Affine(2, 0, 0, 0, -2, 0)) as ds:
        ds.scales = (0.5,)
        ds.offsets = (-2.0,)
        ds.write(np.array([[-32768, -32767, -32766], [-32765, -32764, 10]], np.int16), 1)
    data = dio.read_raster(path).data
    assert np.isnan(data.ravel()[:5]).all()
    assert data[1, 2] == 3.0
