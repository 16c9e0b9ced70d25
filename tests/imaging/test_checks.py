"""demtool.imaging.checks: input content checks with one-line messages naming the file."""

import numpy as np
import pytest
from affine import Affine

from demtool.errors import InputError
from demtool.imaging import checks
from demtool.io import Raster


def _fractal(size, beta, seed):
    """Zero-mean unit-std Gaussian field with power spectrum P(k) ∝ k^-beta."""
    rng = np.random.default_rng(seed)
    ky = np.fft.fftfreq(size)[:, None]
    kx = np.fft.rfftfreq(size)[None, :]
    k = np.hypot(kx, ky)
    k[0, 0] = 1.0
    spectrum = (rng.normal(size=k.shape) + 1j * rng.normal(size=k.shape)) * k ** (-beta / 2)
    spectrum[0, 0] = 0.0
    field = np.fft.irfft2(spectrum, s=(size, size))
    return field / field.std()


def _shaded(size=256, contrast_dn=2.0, mean_dn=80.0, gain=20.0, read_noise=1.0, seed=0):
    """A low-texture planetary image: Lambert-shaded fractal relief, photon + read noise, 8 bit.

    Relief with a lunar-like spectrum (beta = 3.2) under a 60° sun; the shading is
    scaled to ``contrast_dn`` DN standard deviation about ``mean_dn``.  Noise: Poisson
    with ``gain`` e-/DN (σ ≈ sqrt(mean/gain) = 2 DN here) plus read noise, then
    rounding to integer DN.
    """
    rng = np.random.default_rng(seed + 1)
    height = _fractal(size, 3.2, seed) * 3.0
    gy, gx = np.gradient(height)
    normal = np.stack([-gx, -gy, np.ones_like(gx)])
    normal /= np.linalg.norm(normal, axis=0)
    sun = np.array([np.sin(np.radians(60)), 0.0, np.cos(np.radians(60))])
    shading = np.clip(np.tensordot(sun, normal, axes=1), 0, None)
    shading = (shading - shading.mean()) / shading.std()
    radiance = mean_dn + contrast_dn * shading
    electrons = rng.poisson(np.clip(radiance, 0, None) * gain) / gain
    return np.round(electrons + rng.normal(0, read_noise, electrons.shape)).clip(0, 255)


def test_noise_estimate_recovers_known_gaussian_noise():
    rng = np.random.default_rng(3)
    smooth = 100 + 20 * _fractal(512, 4.0, 1)  # smooth structure barely touches the estimate
    for sigma in (0.5, 2.0, 10.0):
        estimate = checks.noise_sigma(smooth + rng.normal(0, sigma, smooth.shape))
        assert estimate == pytest.approx(sigma, rel=0.1)
    assert checks.noise_sigma(np.full((3, 2), 1.0)) == 0.0


def test_weak_but_real_planetary_texture_passes():
    image = _shaded(contrast_dn=2.0)  # 2 DN of shading under ~2.2 DN of noise
    found = checks.check_texture(image, "view_00.tif")
    assert found.noise_sigma == pytest.approx(np.sqrt(80 / 20 + 1 + 1 / 12), rel=0.15)
    assert found.snr > 2 * checks.MIN_TEXTURE_SNR
    # Weaker still: shading at 1/2 of the pixel noise passes too.
    assert checks.check_texture(_shaded(contrast_dn=1.1, seed=5), "weak.tif").snr > \
        1.5 * checks.MIN_TEXTURE_SNR


@pytest.mark.parametrize("name, make", [
    ("constant", lambda rng: np.full((128, 128), 117.0)),
    ("all zero", lambda rng: np.zeros((64, 96))),
    ("noise on a flat field",
     lambda rng: np.round(80 + rng.normal(0, 2.2, (256, 256)))),
    ("1-bit dither", lambda rng: 100.0 + (rng.random((128, 128)) < 0.3)),
    ("hot pixels", lambda rng: np.where(rng.random((128, 128)) < 0.003, 4095.0, 20.0)),
    ("shading at 1/10 of the noise", lambda rng: _shaded(contrast_dn=0.2, seed=7)),
])
def test_constant_and_near_constant_images_are_refused(name, make):
    image = make(np.random.default_rng(11))
    with pytest.raises(InputError, match=r"^left\.tif: left image has no usable texture \(.*\); "
                                         r"is it blank, saturated or the wrong file\?$"):
        checks.check_texture(image, "left.tif", what="left image")


def test_constant_message_names_the_value_and_nan_is_ignored():
    image = np.full((40, 40), 7.0)
    image[:5] = np.nan
    with pytest.raises(InputError, match="every valid pixel is 7"):
        checks.check_texture(image, "x.tif")


def test_a_small_body_on_black_sky_passes():
    image = np.zeros((256, 256))
    body = _shaded(size=128, contrast_dn=8.0, mean_dn=120.0, seed=3)
    image[64:192, 64:192] = body  # a quarter of the frame
    assert checks.check_texture(image, "comet.tif").snr > 10


def test_disparity_range_masks_few_and_refuses_most():
    rng = np.random.default_rng(0)
    disparity = rng.uniform(-10, 20, (50, 60)).astype(np.float32)
    disparity[0, :5] = [1e27, -1e6, 60.0, -25.0, np.nan]
    result = checks.check_disparity_range(disparity, (-10.0, 20.0), "d.tif")
    # margin = max(4, 0.25 * 30) = 7.5 px: -25 and 60 are outside, 1e27 and -1e6 too.
    assert (result.low, result.high) == (-17.5, 27.5)
    assert result.outside == 4
    assert np.isnan(result.disparity[0, :5]).all()
    np.testing.assert_array_equal(result.disparity[1:], disparity[1:])
    assert disparity[0, 0] == np.float32(1e27)  # the input is not modified
    with pytest.raises(InputError, match=r"^d\.tif: 100 % of the disparities lie outside "
                                         r"-17\.5 … 27\.5 px, the range of r\.npz .*1e\+27"):
        checks.check_disparity_range(np.full((4, 4), 1e27), (-10, 20), "d.tif", source="r.npz")
    uint16 = rng.integers(0, 65535, (40, 40)).astype(np.float32)  # a uint16 raster
    with pytest.raises(InputError, match="is it a disparity of this pair"):
        checks.check_disparity_range(uint16, (-10, 20), "u.tif")
    with pytest.raises(InputError, match="no valid"):
        checks.check_disparity_range(np.full((3, 3), np.nan), (-10, 20), "n.tif")
    with pytest.raises(InputError, match=r"r\.npz: disparity range 5 … 1 is not a valid"):
        checks.check_disparity_range(disparity, (5, 1), "d.tif", source="r.npz")


def _rect():
    return {"size_left": np.array([100, 80]), "size_right": np.array([90, 80]),
            "size_rect": np.array([120, 85]), "left_name": np.asarray("view_00"),
            "right_name": np.asarray("view_01")}


def test_rectification_must_match_the_images():
    rect = _rect()
    checks.check_rectification_matches(rect, "r.npz", {"l.tif": (80, 100), "r.tif": (80, 90)},
                                       rectified=False)
    checks.check_rectification_matches(rect, "r.npz", {"l.tif": (85, 120), "r.tif": (85, 120)},
                                       rectified=True,
                                       sources={"l.tif": "view_00", "r.tif": None})
    with pytest.raises(InputError, match=r"^r\.tif: 100 x 80 px, but r\.npz describes a 90 x 80 "
                                         r"px original image; is it the rectification of this"):
        checks.check_rectification_matches(rect, "r.npz",
                                           {"l.tif": (80, 100), "r.tif": (80, 100)},
                                           rectified=False)
    with pytest.raises(InputError, match=r"^l\.tif: 100 x 80 px, but r\.npz describes a 120 x 85 "
                                         r"px rectified canvas"):
        checks.check_rectification_matches(rect, "r.npz", {"l.tif": (80, 100), "r.tif": (85, 120)},
                                           rectified=True)
    with pytest.raises(InputError, match=r"^r\.tif: rectified from view_07, but r\.npz rectifies "
                                         r"view_01"):
        checks.check_rectification_matches(rect, "r.npz", {"l.tif": (85, 120), "r.tif": (85, 120)},
                                           rectified=True,
                                           sources={"l.tif": "view_00", "r.tif": "view_07"})


GRID = Affine(2, 0, 100, 0, -2, 50)


def _raster(shape=(10, 12), transform=GRID, crs=None, frame="image:view_00", path="dem.tif"):
    return Raster(np.zeros(shape, np.float32), transform, crs,
                  {"frame": frame} if frame else {}, path)


def test_mask_must_share_the_grid_and_frame_of_the_dem():
    dem = _raster()
    checks.check_same_grid(dem, _raster(path="mask.tif"))
    checks.check_same_grid(dem, _raster(path="mask.tif", frame=None))  # untagged: no verdict
    cases = [
        (_raster(shape=(10, 13), path="m.tif"), r"m\.tif: mask is 13 x 10 px but the DEM dem\.tif "
                                                r"is 12 x 10 px"),
        (_raster(transform=Affine(2, 0, 102, 0, -2, 50), path="m.tif"), r"m\.tif: mask grid"),
        (_raster(transform=Affine(1, 0, 100, 0, -1, 50), path="m.tif"), r"m\.tif: mask grid"),
        (_raster(crs="EPSG:32633", path="m.tif"), r"m\.tif: mask CRS EPSG:32633 differs"),
        (_raster(frame="image:view_03", path="m.tif"), r"m\.tif: mask is in the frame "
                                                       r"image:view_03, the DEM dem\.tif in "
                                                       r"image:view_00"),
    ]
    for other, message in cases:
        with pytest.raises(InputError, match=message):
            checks.check_same_grid(dem, other)


def test_nan_only_and_absurd_values():
    checks.check_has_valid(np.array([np.nan, 1.0]), "a.tif")
    with pytest.raises(InputError, match=r"^a\.tif: DEM contains no valid \(finite\) pixel$"):
        checks.check_has_valid(np.full((2, 2), np.nan), "a.tif", "DEM")
    checks.check_magnitude(np.array([-8635.0, 10628.0, 3.39e6, np.nan]), "lola.tif")  # radius ok
    with pytest.raises(InputError, match=r"^ref\.tif: reference DEM has 2 value\(s\) beyond "
                                         r"±1e\+08 m \(up to 3\.4e\+38 m\)"):
        checks.check_magnitude(np.array([1.0, 1e27, -3.4e38]), "ref.tif", what="reference DEM")


def test_large_images_are_binned_and_judged_the_same(monkeypatch):
    """Above MAX_TEXTURE_PIXELS the image is 2 × 2 averaged first: same verdicts."""
    monkeypatch.setattr(checks, "MAX_TEXTURE_PIXELS", 128 * 128)
    weak = _shaded(size=512, contrast_dn=2.0)
    found = checks.check_texture(weak, "big.tif")
    assert found.block >= 4 and found.block % 4 == 0  # measured on a 4× binned image
    assert found.snr > 2 * checks.MIN_TEXTURE_SNR
    rng = np.random.default_rng(2)
    noise = np.round(80 + rng.normal(0, 2.2, (512, 512)))
    noise[:, :100] = np.nan  # NaN-aware averaging
    with pytest.raises(InputError, match=r"^flat\.tif: image has no usable texture"):
        checks.check_texture(noise, "flat.tif")
    with pytest.raises(InputError, match="every valid pixel is 7"):
        checks.check_texture(np.full((512, 512), 7.0), "flat.tif")
