"""ISIS3 cubes of the Apollo Metric Camera: interior orientation and lens distortion as
ISIS's ``ApolloMetricCamera`` (origin at ParentSamples/2, ITRANSS/ITRANSL, zDirection −1,
``ApolloMetricDistortionMap``), the AlphaCube window, the footprint reader, bad input;
and, when ../shared is present, the two Apollo 15 cubes against ISIS's own footprints
and the left → ground → right transfer of SIFT matches."""

from pathlib import Path

import numpy as np
import pytest

from demtool.errors import InputError
from demtool.sensors.isis import read_cube, read_footprint

CUBES = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "sensors" \
    / "apollo15_cubes"
RADIUS_KM, ALTITUDE_KM, FOCAL = 1737.4, 119.0, 76.054
# Camera → body: camera x → body +Y, y → +Z, z → +X (away from the Moon; Apollo looks
# along −z).  J2000 → camera is its transpose, SPICE quaternion (0.5, −0.5, −0.5, −0.5).
CAM_TO_BODY = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
NAIF = {"BODY301_RADII": "(1737.4, 1737.4, 1737.4)",
        "INS-915240_FOCAL_LENGTH": "76.054",
        "INS-915240_ITRANSS": "(0.0, -200.0, 0.0)",
        "INS-915240_ITRANSL": "(0.0, 0.0, 200.0)",
        "INS-915240_PP": "(-0.006, -0.002)",
        "INS-915240_OD_K": "(-1.3361854e-06, 5.2261757e-10, -5.0728336e-14)",
        "INS-915240_DECENTER": "(-5.4958195e-07, -4.608942e-11, 2.965907)"}
FOOTPRINT = b"MULTIPOLYGON (((144.5 -18.75, 146.5 -19.25, 146.0 -21.25, 143.9 -20.7, " \
    b"144.5 -18.75)))"


def _table(name, fields, row, start):
    text = [f"Object = Table\n  Name = {name}\n  StartByte = {start}\n  Records = 1\n"
            f"  Bytes = {8 * len(fields)}\n  ByteOrder = Lsb\n"]
    text += [f"  Group = Field\n    Name = {f}\n    Type = Double\n    Size = 1\n  End_Group\n"
             for f in fields]
    return "".join(text) + "End_Object\n", np.asarray(row, dtype="<f8").tobytes()


def write_cube(path, *, size=22900, alpha=None, naif=None, footprint=FOOTPRINT,
               distance_km=RADIUS_KM + ALTITUDE_KM):
    """A label-only cube with SPICE attached: the camera above (lat 0, lon 0), nadir,
    ``distance_km`` from the body's centre."""
    naif = dict(NAIF if naif is None else naif)
    quat = ["J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3", "ET"]
    xyz = ["J2000X", "J2000Y", "J2000Z", "ET"]
    rows = [("InstrumentPointing", quat, [0.5, -0.5, -0.5, -0.5, 0.0]),
            ("BodyRotation", quat, [1.0, 0.0, 0.0, 0.0, 0.0]),
            ("InstrumentPosition", xyz, [distance_km, 0.0, 0.0, 0.0]),
            ("SunPosition", xyz, [1.5e8, 0.0, 0.0, 0.0])]
    head = 8192
    objects, blobs, start = [], b"", head + 1
    for name, fields, row in rows:
        text, blob = _table(name, fields, row, start)
        objects.append(text)
        blobs += blob
        start += len(blob)
    if footprint is not None:
        objects.append(f"Object = Polygon\n  Name = Footprint\n  StartByte = {start}\n"
                       f"  Bytes = {len(footprint)}\nEnd_Object\n")
        blobs += footprint
    alpha_text = "" if alpha is None else "  Group = AlphaCube\n" + "".join(
        f"    {k} = {v}\n" for k, v in alpha.items()) + "  End_Group\n"
    samples = size if alpha is None else alpha["BetaSamples"]
    label = ("Object = IsisCube\n  Object = Core\n    StartByte = 1\n"
             f"    Group = Dimensions\n      Samples = {samples}\n      Lines = {samples}\n"
             "      Bands = 1\n    End_Group\n  End_Object\n"
             "  Group = Kernels\n    NaifFrameCode = -915240\n  End_Group\n"
             + alpha_text + "End_Object\n" + "".join(objects)
             + "Object = NaifKeywords\n" + "".join(f"  {k} = {v}\n" for k, v in naif.items())
             + "End_Object\nEnd\n").encode()
    assert len(label) < head
    path.write_bytes(label + b"\0" * (head - len(label)) + blobs)
    return path


def _sphere_hit(origin, direction, radius):
    b = origin @ direction
    return origin + (-b - np.sqrt(b * b - origin @ origin + radius ** 2)) * direction


def test_apollo_interior_orientation_is_isis(tmp_path):
    model = read_cube(write_cube(tmp_path / "full.cub"))
    assert model.distortion.model == "apollometric" and model.notes == []
    np.testing.assert_allclose(model.rotation, CAM_TO_BODY, atol=1e-15)
    # ISIS's detector origin is sample = line = 22900 / 2 = 11450 (ISIS, 1-based), the
    # CSM pixel 11449.5.  The distorted focal-plane point (40, −30) mm is sample
    # 11449.5 − 200·40, line 11449.5 + 200·(−30); ISIS's distortion map takes it to
    # (39.971620676, −29.970366527) mm about the principal point (see
    # test_distortion.py), and the ray is R (u, v, −f).
    ray = model.image_to_ray(np.array([5449.5]), np.array([3449.5]))
    look = CAM_TO_BODY @ np.array([39.971620676, -29.970366527, -FOCAL])
    np.testing.assert_allclose(ray.direction[0], look / np.linalg.norm(look), atol=1e-10)
    # Exactly on the origin the ray leaves along the principal point's offset.
    ray = model.image_to_ray(np.array([11449.5]), np.array([11449.5]))
    look = CAM_TO_BODY @ np.array([0.006, 0.002, -FOCAL])
    np.testing.assert_allclose(ray.direction[0], look / np.linalg.norm(look), atol=1e-12)
    # And to the ground and back: the model's ground point is the ray's sphere hit.
    ground = model.image_to_ground(np.array([5449.5]), np.array([3449.5]))[0]
    origin = np.array([RADIUS_KM + ALTITUDE_KM, 0, 0]) * 1e3
    look = CAM_TO_BODY @ np.array([39.971620676, -29.970366527, -FOCAL])
    expected = _sphere_hit(origin, look / np.linalg.norm(look), RADIUS_KM * 1e3)
    np.testing.assert_allclose(ground, expected, atol=1e-3)
    line, sample = model.ground_to_image(ground)
    assert line == pytest.approx(5449.5, abs=1e-6) and sample == pytest.approx(3449.5, abs=1e-6)


def test_alphacube_window_maps_to_the_full_scan(tmp_path):
    # The shared cubes' window: a 7988-pixel square from (7996.5, 3996.5) in 500 pixels.
    alpha = {"AlphaSamples": 22900, "AlphaLines": 22900, "AlphaStartingSample": 7996.5,
             "AlphaStartingLine": 3996.5, "AlphaEndingSample": 15984.5,
             "AlphaEndingLine": 11984.5, "BetaSamples": 500, "BetaLines": 500}
    crop = read_cube(write_cube(tmp_path / "crop.cub", alpha=alpha))
    full = read_cube(write_cube(tmp_path / "full.cub"))
    # ISIS AlphaCube: alpha = start + (end − start) / beta_size · (beta − 0.5), 1-based.
    beta = np.array([1.0, 250.5, 500.0])
    alpha_s = 7996.5 + 7988 / 500 * (beta - 0.5)
    alpha_l = 3996.5 + 7988 / 500 * (beta - 0.5)
    a = crop.image_to_ground(beta - 0.5, beta - 0.5)
    b = full.image_to_ground(alpha_l - 0.5, alpha_s - 0.5)
    np.testing.assert_allclose(a, b, atol=1e-4)
    assert crop.image_size == (500, 500)


def test_apollo_cube_model_survives_an_isd_round_trip(tmp_path):
    # bundle writes adjusted cubes as ISDs: the distortion goes with them (as an
    # ``apollometric`` block, which demtool reads back; usgscsm has no such model).
    from demtool.sensors.isd import isd_from_sensor, sensor_from_isd

    model = read_cube(write_cube(tmp_path / "full.cub"))
    isd = isd_from_sensor(model)
    assert list(isd["optical_distortion"]) == ["apollometric"]
    again = sensor_from_isd(isd)
    line, sample = np.meshgrid(np.linspace(0.5, 22899.5, 5), np.linspace(0.5, 22899.5, 5))
    np.testing.assert_allclose(again.image_to_ground(line, sample),
                               model.image_to_ground(line, sample), atol=1e-6)


def test_other_instruments_with_distortion_keywords_are_refused(tmp_path):
    naif = {k.replace("915240", "123456"): v for k, v in NAIF.items()}
    path = write_cube(tmp_path / "other.cub", naif=naif)
    text = path.read_bytes().replace(b"NaifFrameCode = -915240", b"NaifFrameCode = -123456")
    path.write_bytes(text)
    with pytest.raises(InputError, match=r"other\.cub: the ISIS camera of NAIF code -123456 "
                                         r"models lens distortion \(INS-123456_DECENTER\)"):
        read_cube(path)
    # without distortion keywords the camera is ideal, and says nothing
    naif = {k: v for k, v in naif.items() if not k.endswith(("_PP", "_OD_K", "_DECENTER"))}
    path = write_cube(tmp_path / "ideal.cub", naif=naif)
    path.write_bytes(path.read_bytes().replace(b"NaifFrameCode = -915240",
                                               b"NaifFrameCode = -123456"))
    model = read_cube(path)
    assert model.distortion.model == "none" and model.notes == []


@pytest.mark.parametrize(("key", "value", "message"), [
    ("INS-915240_OD_K", None, r"lacks the key 'INS-915240_OD_K'"),
    ("INS-915240_DECENTER", "(1.0, 2.0)", r"'INS-915240_DECENTER' has 2 values, expected 3"),
    ("INS-915240_PP", "(1.0, 2.0, 3.0)", r"'INS-915240_PP' has 3 values, expected 2"),
])
def test_bad_apollo_distortion_keywords(tmp_path, key, value, message):
    naif = dict(NAIF)
    if value is None:
        del naif[key]
    else:
        naif[key] = value
    with pytest.raises(InputError, match=r"bad\.cub: NaifKeywords " + message):
        read_cube(write_cube(tmp_path / "bad.cub", naif=naif))


def test_read_footprint(tmp_path):
    rings = read_footprint(write_cube(tmp_path / "f.cub"))
    assert len(rings) == 1
    np.testing.assert_allclose(rings[0], [[144.5, -18.75], [146.5, -19.25], [146.0, -21.25],
                                          [143.9, -20.7]])


@pytest.mark.parametrize(("footprint", "message"), [
    (None, r"no footprint polygon \(run footprintinit\)"),
    (b"<gml:MultiPolygon/>", "not WKT"),
    (b"MULTIPOLYGON (((1 2, 3 4, 1 2)))", "malformed ring"),
    (b"MULTIPOLYGON (((1 2 3, 3 4 5, 5 6 7, 1 2 3)))", "malformed ring"),
    (b"MULTIPOLYGON EMPTY", "no ring"),
])
def test_bad_footprint(tmp_path, footprint, message):
    with pytest.raises(InputError, match=r"f\.cub: .*" + message):
        read_footprint(write_cube(tmp_path / "f.cub", footprint=footprint))


def test_footprint_past_the_end(tmp_path):
    path = write_cube(tmp_path / "f.cub")
    path.write_bytes(path.read_bytes()[:-10])
    with pytest.raises(InputError, match=r"f\.cub: the footprint polygon runs past the end"):
        read_footprint(path)


# ---------------------------------------------------------------------------------------
# The two Apollo 15 cubes (../shared)
# ---------------------------------------------------------------------------------------

HEIGHTS = np.arange(-5000.0, 12000.0, 10.0)


def _shared_cubes():
    left, right = CUBES / "AS15-M-0297_crop.cub", CUBES / "AS15-M-0298_crop.cub"
    if not (left.exists() and right.exists()):
        pytest.skip("../shared/data/sensors/apollo15_cubes is absent")
    return left, right


def _lonlat_xyz(lon, lat, height):
    lon, lat, r = np.radians(lon), np.radians(lat), RADIUS_KM * 1e3 + height
    return np.stack([r * np.cos(lat) * np.cos(lon), r * np.cos(lat) * np.sin(lon),
                     r * np.sin(lat)], axis=-1)


def _footprint_fit(model, ring):
    """Per vertex: closest approach (px) of its ground column (h = −5 … 12 km) to
    footprintinit's border walk (every 100 px of the 500-px crop) and the height there."""
    line, sample = model.ground_to_image(_lonlat_xyz(ring[:, :1], ring[:, 1:], HEIGHTS))

    def walk(v):
        return np.clip(np.round((v - 0.5) / 100) * 100 + 0.5, 0.5, 500.5)

    gap = np.hypot(sample - walk(sample), line - walk(line))
    best = np.argmin(gap, axis=1)
    rows = np.arange(len(ring))
    return gap[rows, best], HEIGHTS[best]


@pytest.mark.data
def test_apollo15_cubes_reproduce_isis_footprints():
    # ISIS's footprintinit walked each crop's border with ISIS's own camera onto the
    # LOLA shape model; our model sends every vertex back onto its border pixel at
    # some height (median 0.3 px, worst 1.1 px), and that height lies within the LOLA
    # radii ISIS's camera statistics give for the full frames (−2.3 … +6.4 km).
    for path in _shared_cubes():
        gap, height = _footprint_fit(read_cube(path), read_footprint(path)[0])
        assert np.median(gap) < 0.5 and gap.max() < 1.5, path.name
        assert -2500 < height.min() and height.max() < 7000, path.name


@pytest.mark.data
def test_apollo15_transfer_residual():
    cv2 = pytest.importorskip("cv2")
    from demtool.io import read_image

    left_path, right_path = _shared_cubes()

    def grey(path):
        a = np.nan_to_num(read_image(path).data.astype(np.float64))
        lo, hi = np.percentile(a, [1, 99])
        return np.clip((a - lo) / (hi - lo) * 255, 0, 255).astype(np.uint8)

    sift = cv2.SIFT_create()
    ka, da = sift.detectAndCompute(grey(left_path), None)
    kb, db = sift.detectAndCompute(grey(right_path), None)
    pairs = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.8 * n.distance]
    pa = np.float64([ka[m.queryIdx].pt for m in pairs])
    pb = np.float64([kb[m.trainIdx].pt for m in pairs])
    _, mask = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.0, 0.999)
    keep = mask.ravel().astype(bool)
    pa, pb = pa[keep] + 0.5, pb[keep] + 0.5
    assert len(pa) > 300
    left, right = read_cube(left_path), read_cube(right_path)

    def residual(height_of):
        h = np.zeros(len(pa))
        for _ in range(5):
            xyz = left.image_to_ground(pa[:, 1], pa[:, 0], h)
            r = np.linalg.norm(xyz, axis=1)
            h = height_of(np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])),
                          np.degrees(np.arcsin(xyz[:, 2] / r)))
        line, sample = right.ground_to_image(xyz)
        return np.column_stack([sample, line]) - pb

    # On the 1737.4 km sphere the transfer misses by 16 px, along track (+sample is
    # east, the flight is westwards): the terrain is kilometres above the sphere and
    # falls eastwards (parallax 2.85 px per km at B/H 0.34 and 126 m pixels).
    d = residual(lambda lon, lat: np.zeros_like(lon))
    assert 13 < np.median(np.hypot(*d.T)) < 19 and np.median(d[:, 0]) < -12
    # On LOLA's heights (from ISIS's footprints, a quadratic in lon/lat) it misses by
    # 6 px: what is left is the SPICE's relative orientation (≈ 5 px along track,
    # ≈ 2.6 px across) — bundle's job, not the camera model's.
    points = []
    for model, path in ((left, left_path), (right, right_path)):
        ring = read_footprint(path)[0]
        points.append(np.column_stack([ring, _footprint_fit(model, ring)[1]]))
    pts = np.concatenate(points)

    def design(lon, lat):
        u, v = lon - 145.0, lat + 20.0
        return np.column_stack([np.ones_like(u), u, v, u * u, u * v, v * v])

    coef, *_ = np.linalg.lstsq(design(pts[:, 0], pts[:, 1]), pts[:, 2], rcond=None)
    d = residual(lambda lon, lat: design(lon, lat) @ coef)
    n = np.hypot(*d.T)
    assert np.median(n) < 7.5 and np.percentile(n, 90) < 10
    assert abs(np.median(d[:, 0])) < 7 and abs(np.median(d[:, 1])) < 4
