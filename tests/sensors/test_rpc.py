"""RPC00B sensor: the Newton inverse against closed forms and round trips, WGS84
geodesy against PROJ, every file source reading to GDAL's model, bad input in one line."""

import warnings

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
    xyz_to_geodetic,
)
from demtool.sensors.rpc_files import read_rpc

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


def write_geom(path, rpc, *, fmt="B", prefix="", extra=()):
    """An OSSIM keyword list as ``ossimRpcModel::saveState`` writes it."""
    from demtool.sensors.rpc_files import A_TO_B

    lines = [f"{prefix}type: ossimRpcModel", f"{prefix}polynomial_format: {fmt}"]
    lines += [f"{prefix}{k}: {rpc[k]!r}" for k in SCALARS]
    for key in COEFFS:
        values = np.asarray(rpc[key], dtype=np.float64)
        if fmt == "A":
            values = values[list(A_TO_B)]
        lines += [f"{prefix}{key}_{i:02d}: {float(v)!r}" for i, v in enumerate(values)]
    path.write_text("\n".join(lines + list(extra)) + "\n")
    return path


def write_tif(path, rpc=None, size=(100, 80)):
    import rasterio
    from rasterio.rpc import RPC

    rpcs = None if rpc is None else RPC(**{k: (list(v) if k in COEFFS else v)
                                           for k, v in rpc.items()})
    with warnings.catch_warnings():  # a plain image beside an .RPB has no georeferencing
        warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
        with rasterio.open(path, "w", driver="GTiff", width=size[1], height=size[0],
                           count=1, dtype="uint8", rpcs=rpcs) as ds:
            ds.write(np.zeros((1,) + size, np.uint8))
    return path


def gdal_rpcs(path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.rpcs


def assert_same_as_gdal(model, rpcs):
    """image -> lon/lat/h within 1e-7 deg and lon/lat/h -> image within 0.01 px of GDAL's
    RPC transformer (its pixel corner (0, 0) is the CSM origin)."""
    from rasterio.transform import RPCTransformer

    line, sample = np.meshgrid(np.linspace(3.0, 97.0, 5), np.linspace(2.0, 78.0, 5))
    line, sample = line.ravel(), sample.ravel()
    # GDAL stops its inverse at 0.1 px by default: ask it for 1e-6 px
    with RPCTransformer(rpcs, RPC_PIXEL_ERROR_THRESHOLD=1e-6) as gdal:
        for height in (100.0, 500.0, 1100.0):
            zs = np.full(line.shape, height)
            lon_g, lat_g = gdal.xy(line, sample, zs=zs, offset="ul")
            lon, lat = model.image_to_lonlat(line, sample, height)
            np.testing.assert_allclose(lon, lon_g, atol=1e-7)
            np.testing.assert_allclose(lat, lat_g, atol=1e-7)
            row_g, col_g = gdal.rowcol(np.asarray(lon_g), np.asarray(lat_g), zs=zs,
                                       op=lambda v: v)
            got_line, got_sample = model.lonlat_to_image(lon_g, lat_g, height)
            np.testing.assert_allclose(got_line, row_g, atol=0.01)
            np.testing.assert_allclose(got_sample, col_g, atol=0.01)


def test_every_rpc_source_reads_to_gdals_model(tmp_path):
    import rasterio.shutil

    rpc = rpc_dict()
    tif = write_tif(tmp_path / "scene.tif", rpc)
    ntf = tmp_path / "scene.ntf"
    rasterio.shutil.copy(tif, ntf, driver="NITF")  # GDAL's NITF driver writes an RPC00B TRE
    write_tif(tmp_path / "beside.tif")
    rpb_beside = write_rpb(tmp_path / "beside.RPB", rpc)
    txt = write_rpc_txt(tmp_path / "alone_RPC.TXT", rpc)
    rpb = write_rpb(tmp_path / "other.RPB", rpc)
    sources = {tif: gdal_rpcs(tif), ntf: gdal_rpcs(ntf), rpb_beside: gdal_rpcs(
        tmp_path / "beside.tif"), txt: gdal_rpcs(tif), rpb: gdal_rpcs(tif),
        write_geom(tmp_path / "b.geom", rpc): gdal_rpcs(tif),
        write_geom(tmp_path / "a.geom", rpc, fmt="A", prefix="image0."): gdal_rpcs(tif)}
    for path, rpcs in sources.items():
        model = read_sensor(path)
        assert isinstance(model, RpcSensor), path
        assert_same_as_gdal(model, rpcs)
    # sizes: the image's own (GeoTIFF, NITF, the image beside the .RPB), none otherwise
    assert [read_sensor(p).image_size for p in sources] == [(100, 80)] * 3 + [(0, 0)] * 4
    write_tif(tmp_path / "b.tif", size=(30, 20))  # OTB's img.geom beside img.tif
    assert read_sensor(tmp_path / "b.geom").image_size == (30, 20)
    assert read_sensor(rpb).notes == ["the RPC file gives no image size and no image lies "
                                      "beside it"]


def test_geom_sub_image_offset_moves_the_image(tmp_path):
    rpc = rpc_dict()
    whole = RpcSensor(rpc)
    crop = read_rpc(write_geom(tmp_path / "crop.geom", rpc,
                               extra=["sub_image_offset: 120.0 250.0"]))
    line, sample = whole.lonlat_to_image(5.01, 45.02, 300.0)
    got = crop.lonlat_to_image(5.01, 45.02, 300.0)
    np.testing.assert_allclose(got, (line - 250.0, sample - 120.0), atol=1e-9)


def test_validity_domain():
    model = RpcSensor(rpc_dict())
    domain = model.domain()
    assert domain["lon"] == pytest.approx((4.93, 5.07))
    assert domain["lat"] == pytest.approx((44.95, 45.05))
    assert domain["height"] == (-300.0, 1300.0)
    assert model.domain_problem([5.0, 5.06], [45.0, 45.04], [0.0, 1500.0]) is None
    assert model.domain_problem(5.0, 45.0, 9000.0) == (
        "height 9000 m lies outside the RPC's validity domain -300…1300 m")
    assert "latitude 46.2° lies outside" in model.domain_problem(5.0, 46.2, 0.0)
    # longitudes are compared on the domain's side of the antimeridian
    assert model.domain_problem(365.0, 45.0, 0.0) is None


def _zero_den(rpc):
    return dict(rpc, samp_den_coeff=np.zeros(20))


def _vanishing_den(rpc):
    den = np.zeros(20)
    den[[0, 1]] = [0.5, 1.0]  # 0.5 + L crosses zero at L = -0.5
    return dict(rpc, line_den_coeff=den)


@pytest.mark.parametrize("edit, match", [
    (lambda r: dict(r, height_scale=0.0), r"'HEIGHT_SCALE' is 0: scales must be non-zero"),
    (_zero_den, r"'SAMP_DEN_COEFF' is all zeros: the samp polynomial has no denominator"),
    (_vanishing_den, r"'LINE_DEN_COEFF' vanishes inside the RPC's validity domain"),
])
def test_impossible_models_are_refused_naming_the_value(tmp_path, edit, match):
    for path in (write_rpc_txt(tmp_path / "bad_RPC.TXT", edit(rpc_dict())),
                 write_geom(tmp_path / "bad.geom", edit(rpc_dict())),
                 write_tif(tmp_path / "bad.tif", edit(rpc_dict()))):
        with pytest.raises(InputError, match=rf"^{path}: {match}"):
            read_sensor(path)


def test_truncated_and_malformed_files_are_one_line(tmp_path):
    text = write_rpc_txt(tmp_path / "t_RPC.TXT", rpc_dict()).read_text()
    (tmp_path / "t_RPC.TXT").write_text("\n".join(
        ln for ln in text.splitlines() if not ln.startswith("SAMP_DEN_COEFF_20:")))
    with pytest.raises(InputError, match=r"t_RPC\.TXT: 'SAMP_DEN_COEFF' has 19 coefficients, "
                                         "expected 20$"):
        read_rpc(tmp_path / "t_RPC.TXT")
    path = write_rpb(tmp_path / "short.RPB", dict(rpc_dict(), samp_num_coeff=np.ones(19)))
    with pytest.raises(InputError, match=r"short\.RPB: 'SAMP_NUM_COEFF' has 19 coefficients"):
        read_rpc(path)
    path = write_geom(tmp_path / "short.geom", rpc_dict())
    path.write_text(path.read_text().replace("samp_den_coeff_07", "samp_den_coeff_x"))
    with pytest.raises(InputError, match=r"short\.geom: 'samp_den_coeff' has 19 coefficients, "
                                         r"expected 20 \(samp_den_coeff_07 missing\)"):
        read_rpc(path)
    path = write_geom(tmp_path / "nolat.geom", rpc_dict())
    path.write_text(path.read_text().replace("lat_off: 45.0", "lat_off: north"))
    with pytest.raises(InputError, match=r"nolat\.geom: 'lat_off' is not a number"):
        read_rpc(path)


def test_raster_without_rpc_is_refused(tmp_path):
    from affine import Affine

    from demtool import io as dio

    tif = tmp_path / "plain.tif"
    dio.write_raster(tif, np.zeros((4, 4), np.float32), crs="EPSG:4326",
                     transform=Affine(0.1, 0.0, 5.0, 0.0, -0.1, 45.0))
    with pytest.raises(InputError, match=r"plain\.tif: not a sensor model: GDAL finds no RPC"):
        read_sensor(tif)
