"""RPC00B sensor: the Newton inverse against closed forms and round trips, WGS84
geodesy against PROJ, the three file formats agreeing, bad input in one line."""

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors import read_sensor
from demtool.sensors.rpc import (
    COEFFS,
    SCALARS,
    WGS84,
    RpcSensor,
    geodetic_to_xyz,
    read_rpc,
    xyz_to_geodetic,
)

OFFSETS = {"line_off": 5000.0, "samp_off": 4000.0, "lat_off": 45.0, "long_off": 5.0,
           "height_off": 500.0, "line_scale": 5000.0, "samp_scale": 4000.0,
           "lat_scale": 0.05, "long_scale": 0.07, "height_scale": 800.0}


def rpc_dict(linear=False):
    """A pushbroom-like RPC: line mostly −latitude, sample mostly longitude, parallax in
    height, small cubic and rational terms (unless ``linear``)."""
    line_num, samp_num = np.zeros(20), np.zeros(20)
    line_den, samp_den = np.zeros(20), np.zeros(20)
    line_num[[1, 2, 3]] = [0.02, -1.0, 0.05]
    samp_num[[1, 2, 3]] = [1.0, 0.01, -0.03]
    line_den[0] = samp_den[0] = 1.0
    if not linear:
        line_num[[4, 7, 8, 11, 15]] = [1e-3, -2e-3, 3e-3, 1e-4, -2e-4]
        samp_num[[4, 7, 8, 12, 14]] = [-1e-3, 2e-3, 1e-3, 1e-4, 5e-5]
        line_den[[1, 2, 3]] = [1e-4, -2e-4, 1e-5]
        samp_den[[1, 2, 3]] = [-1e-4, 1e-4, 2e-5]
    return dict(OFFSETS, line_num_coeff=line_num, line_den_coeff=line_den,
                samp_num_coeff=samp_num, samp_den_coeff=samp_den)


def test_linear_rpc_inverse_matches_the_closed_form():
    model = RpcSensor(rpc_dict(linear=True), lines=10000, samples=8000)
    line, sample, height = 1234.5, 6789.25, 900.0
    H = (height - 500.0) / 800.0
    # line_n = 0.02 L − P + 0.05 H ; samp_n = L + 0.01 P − 0.03 H
    ln, sn = (line - 0.5 - 5000.0) / 5000.0, (sample - 0.5 - 4000.0) / 4000.0
    a = np.array([[0.02, -1.0], [1.0, 0.01]])
    L, P = np.linalg.solve(a, [ln - 0.05 * H, sn + 0.03 * H])
    lon, lat = model.image_to_lonlat(line, sample, height)
    assert lon == pytest.approx(5.0 + 0.07 * L, abs=1e-12)
    assert lat == pytest.approx(45.0 + 0.05 * P, abs=1e-12)


def test_round_trip_over_the_image_and_heights():
    model = RpcSensor(rpc_dict(), lines=10000, samples=8000)
    line, sample = np.meshgrid(np.linspace(0.5, 9999.5, 11), np.linspace(0.5, 7999.5, 9),
                               indexing="ij")
    for height in (-300.0, 500.0, 1300.0):
        ground = model.image_to_ground(line, sample, height)
        back_line, back_sample = model.ground_to_image(ground)
        np.testing.assert_allclose(back_line, line, atol=1e-6)
        np.testing.assert_allclose(back_sample, sample, atol=1e-6)
        # the ground point lies at the asked geodetic height
        np.testing.assert_allclose(xyz_to_geodetic(ground, WGS84)[2], height, atol=1e-6)
    # the ray passes through the ground points of every height
    ray = model.image_to_ray(line, sample)
    ground = model.image_to_ground(line, sample, 200.0)
    off = ground - ray.origin
    along = np.sum(off * ray.direction, -1)[..., None] * ray.direction
    miss = np.linalg.norm(off - along, axis=-1)
    # metres (0.073 measured, 0.07 px): an RPC's lines of sight are not exactly straight
    assert miss.max() < 0.1


def test_wgs84_geodesy_matches_proj():
    from pyproj import Transformer

    lon, lat, h = np.array([5.0, -120.3, 179.9]), np.array([45.0, -33.2, 89.5]), \
        np.array([500.0, -50.0, 3000.0])
    xyz = geodetic_to_xyz(lon, lat, h, WGS84)
    want = np.column_stack(Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
                           .transform(lon, lat, h))
    np.testing.assert_allclose(xyz, want, atol=1e-6)
    back = xyz_to_geodetic(xyz, WGS84)
    np.testing.assert_allclose(back[0], lon, atol=1e-10)
    np.testing.assert_allclose(back[1], lat, atol=1e-10)
    np.testing.assert_allclose(back[2], h, atol=1e-6)


def write_rpc_txt(path, rpc):
    lines = [f"{SCALARS[k][0]}: {rpc[k]!r} {'pixels' if 'line' in k or 'samp' in k else ''}"
             for k in SCALARS]
    for key, (name, _) in COEFFS.items():
        lines += [f"{name}_{i + 1}: {float(v)!r}" for i, v in enumerate(rpc[key])]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_rpb(path, rpc):
    lines = ['satId = "WV02";', 'bandId = "P";', "BEGIN_GROUP = IMAGE"]
    lines += [f"\t{SCALARS[k][1]} = {rpc[k]!r};" for k in SCALARS]
    for key, (_, name) in COEFFS.items():
        values = [f"\t\t\t{float(v)!r}" for v in rpc[key]]
        lines += [f"\t{name} = ("] + [v + "," for v in values[:-1]] + [values[-1] + ");"]
    lines += ["END_GROUP = IMAGE", "END;"]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_rpc_txt_rpb_and_geotiff_read_the_same_model(tmp_path):
    import rasterio
    from rasterio.rpc import RPC

    rpc = rpc_dict()
    tif = tmp_path / "scene.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=80, height=100, count=1, dtype="uint8",
                       rpcs=RPC(**{k: (list(v) if k in COEFFS else v)
                                   for k, v in rpc.items()})) as ds:
        ds.write(np.zeros((1, 100, 80), np.uint8))
    models = [read_sensor(write_rpc_txt(tmp_path / "scene_RPC.TXT", rpc)),
              read_sensor(write_rpb(tmp_path / "other.RPB", rpc)), read_sensor(tif)]
    assert all(isinstance(m, RpcSensor) for m in models)
    # sizes: the GeoTIFF's own, the image beside the _RPC.TXT, none for the lone .RPB
    assert [m.image_size for m in models] == [(100, 80), (0, 0), (100, 80)]
    assert models[1].notes == ["the RPC file gives no image size and no image lies beside it"]
    ground = geodetic_to_xyz(np.array([5.01, 4.98]), np.array([45.02, 44.97]),
                             np.array([100.0, 900.0]), WGS84)
    want = RpcSensor(rpc).ground_to_image(ground)
    for model in models:  # GDAL stores the tags as text: 15 significant digits
        np.testing.assert_allclose(model.ground_to_image(ground), want, atol=1e-6)


@pytest.mark.parametrize("edit, match", [
    (lambda t: t.replace("LINE_NUM_COEFF_3: ", "LINE_NUM_COEFF_3: x"),
     r"bad_RPC\.TXT: line 13: 'LINE_NUM_COEFF_3' is not a number"),
    (lambda t: t.replace("LINE_NUM_COEFF_3: ", "LINE_NUM_COEFF_3 "),
     r"bad_RPC\.TXT: line 13: cannot parse"),
    (lambda t: t.replace("SAMP_DEN_COEFF_20", "SAMP_DEN_COEFF_21"),
     r"bad_RPC\.TXT: line 90: 'SAMP_DEN_COEFF_21': coefficients are numbered 1 to 20"),
    (lambda t: "\n".join(ln for ln in t.splitlines() if not ln.startswith("SAMP_DEN_COEFF_7:")),
     r"bad_RPC\.TXT: lacks the RPC key 'SAMP_DEN_COEFF_7'"),
    (lambda t: t.replace("HEIGHT_SCALE: 800.0", "HEIGHT_SCALE: 0.0"),
     r"bad_RPC\.TXT: 'height_scale' is 0\.0: scales must be non-zero"),
])
def test_malformed_rpc_txt_is_one_line_naming_file_and_line(tmp_path, edit, match):
    path = write_rpc_txt(tmp_path / "bad_RPC.TXT", rpc_dict())
    path.write_text(edit(path.read_text()))
    with pytest.raises(InputError, match=match):
        read_rpc(path)


def test_malformed_rpb_is_one_line_naming_file_and_line(tmp_path):
    path = write_rpb(tmp_path / "bad.RPB", rpc_dict())
    lines = path.read_text().splitlines()
    where = next(i for i, ln in enumerate(lines) if "lineDenCoef" in ln) + 3
    lines[where] = "\t\t\t1.0e-0q,"
    path.write_text("\n".join(lines))
    with pytest.raises(InputError, match=rf"bad\.RPB: line {where + 1}: 'line_den_coeff' is "
                                         "not a number"):
        read_rpc(path)
    path = write_rpb(tmp_path / "short.RPB", dict(rpc_dict(), samp_num_coeff=np.ones(19)))
    with pytest.raises(InputError, match=r"short\.RPB: 'sampNumCoef' has 19 coefficients"):
        read_rpc(path)


def test_geotiff_without_rpc_tags_is_refused(tmp_path):
    from affine import Affine

    from demtool import io as dio

    tif = tmp_path / "plain.tif"
    dio.write_raster(tif, np.zeros((4, 4), np.float32), crs="EPSG:4326",
                     transform=Affine(0.1, 0.0, 5.0, 0.0, -0.1, 45.0))
    with pytest.raises(InputError, match=r"plain\.tif: not a sensor model: the GeoTIFF "
                                         r"carries no RPC tags"):
        read_sensor(tif)
