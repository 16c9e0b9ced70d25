"""Every distortion model: remove(apply(p)) == p and the published closed forms."""

import numpy as np
import pytest

from demtool.sensors.distortion import Distortion

# Coefficients of real instruments (ALE ISDs / instrument kernels) where one is at hand,
# otherwise strong enough to move the corners by many pixels.
MODELS = {
    "radial": ([-1e-3, 2e-6, -1e-9], 60.0, 1.0),
    "transverse": (np.r_[[0, 1, 0, 1e-5, 2e-5, 0, 1e-6, 0, 2e-6, 0],
                         [0, 0, 1, 0, 1e-5, 3e-5, 0, 2e-6, 0, 1e-6]], 10.0, 1.0),
    "radtan": ([-0.2, 0.05, 1e-3, -2e-3, 0.0], 5.0, 150.0),
    "lrolrocnac": ([1.81e-05], 20.0, 1.0),                                        # LRO NAC
    "dawnfc": ([8.4e-06], 7.0, 1.0),                                              # Dawn FC2
    "kaguyalism": ([1e-3, 1e-4, -2e-4, 1e-5, -1e-6, -2e-3, 2e-4, 1e-4, -1e-5, 2e-6], 5.0, 1.0),
    "cahvor": ([-1e-4, 2e-6, 0.0, 0.3, -0.2], 8.0, 1.0),
    "lunarorbiter": ([1e-4, -2e-4, 0.1, -0.05, -1e-5, 1e-8], 50.0, 1.0),
    "brown": ([-0.25, 0.08, 1e-3, -5e-4, -0.01], 0.6, 1.0),
    # Apollo 15 Metric (NAIF IK INS-915240_PP, _OD_K, _DECENTER), film half-width 57 mm
    "apollometric": ([-0.006, -0.002, -1.3361854e-06, 5.2261757e-10, -5.0728336e-14,
                      -5.4958195e-07, -4.608942e-11, 2.965907], 57.0, 1.0),
}


@pytest.mark.parametrize("model", sorted(MODELS))
def test_apply_then_remove_is_identity(model):
    coefficients, extent, focal = MODELS[model]
    distortion = Distortion(model, coefficients, focal)
    x, y = np.meshgrid(np.linspace(-extent, extent, 21), np.linspace(-extent, extent, 17))
    dx, dy = distortion.apply(x, y)
    assert np.max(np.hypot(dx - x, dy - y)) > 1e-4 * extent  # the model does something
    ux, uy = distortion.remove(dx, dy)
    np.testing.assert_allclose(ux, x, atol=1e-7 * extent)
    np.testing.assert_allclose(uy, y, atol=1e-7 * extent)
    assert dx.shape == x.shape


def test_closed_forms():
    # radial remove: u = d (1 − (k0 + k1 r² + k2 r⁴))
    d = Distortion("radial", [1e-3, 1e-4, 1e-6])
    ux, uy = d.remove(3.0, 4.0)
    dr = 1e-3 + 25 * 1e-4 + 625 * 1e-6
    assert ux == pytest.approx(3 * (1 - dr)) and uy == pytest.approx(4 * (1 - dr))
    # LRO NAC remove: only y, u_y = d_y / (1 + k d_y²)
    d = Distortion("lrolrocnac", [1.81e-5])
    ux, uy = d.remove(2.0, 10.0)
    assert ux == 2.0 and uy == pytest.approx(10.0 / (1 + 1.81e-5 * 100))
    # Dawn FC apply: d = u (1 + k r²)
    d = Distortion("dawnfc", [8.4e-6])
    dx, dy = d.apply(3.0, 4.0)
    assert dx == pytest.approx(3 * (1 + 8.4e-6 * 25))


def test_brown_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    coefficients = np.array([-0.25, 0.08, 1e-3, -5e-4, -0.01])
    pts = np.array([[0.1, -0.2, 1.0], [0.4, 0.3, 1.0], [-0.5, 0.45, 1.0]])
    projected, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.eye(3), coefficients)
    dx, dy = Distortion("brown", coefficients).apply(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(np.column_stack([dx, dy]), projected[:, 0], atol=1e-12)


def test_bad_models_are_refused():
    with pytest.raises(ValueError, match="unknown distortion model"):
        Distortion("fisheye", [1.0])
    with pytest.raises(ValueError, match="coefficients"):
        Distortion("radial", [1.0, 2.0])


AS15_METRIC = [-0.006, -0.002,                                     # INS-915240_PP (mm)
               -1.3361854e-06, 5.2261757e-10, -5.0728336e-14,     # INS-915240_OD_K
               -5.4958195e-07, -4.608942e-11, 2.965907]           # INS-915240_DECENTER


def test_apollometric_is_isis_formula():
    """ISIS ApolloMetricDistortionMap::SetFocalPlane, written out term by term for the
    Apollo 15 Metric Camera's IK coefficients (the values the cubes' NaifKeywords carry)."""
    d = Distortion("apollometric", AS15_METRIC)
    x, y = 40.0 - (-0.006), -30.0 - (-0.002)          # reduced to the principal point
    rr = x * x + y * y
    dr = 1 - 1.3361854e-06 * rr + 5.2261757e-10 * rr ** 2 - 5.0728336e-14 * rr ** 3
    dt = -5.4958195e-07 * rr - 4.608942e-11 * rr ** 2
    ux, uy = d.remove(40.0, -30.0)
    assert ux == pytest.approx(dr * x - dt * np.sin(2.965907), abs=1e-12)
    assert uy == pytest.approx(dr * y + dt * np.cos(2.965907), abs=1e-12)
    # The same numbers as literals (mm): at r = 50 mm the lens moves the point by
    # 36 µm (7 pixels of the 5 µm scan), mostly radially inwards.
    assert ux == pytest.approx(39.971620676, abs=1e-8)
    assert uy == pytest.approx(-29.970366527, abs=1e-8)
    # The principal point itself is undistorted and becomes the optical axis.
    ux, uy = d.remove(-0.006, -0.002)
    assert abs(ux) < 1e-15 and abs(uy) < 1e-15
    # ISIS's inverse (SetUndistortedFocalPlane) converges to 1e-6 mm; ours matches
    # the forward map to that tolerance and better.
    dx, dy = d.apply(39.971620676101544, -29.970366527330520)
    assert dx == pytest.approx(40.0, abs=1e-9) and dy == pytest.approx(-30.0, abs=1e-9)


def test_apollometric_inverse_gives_up_like_isis():
    # Far outside the film (r = 10 m) the fixed-point iteration diverges: ISIS returns
    # false there; the model returns NaN rather than a wrong point.
    d = Distortion("apollometric", AS15_METRIC)
    dx, dy = d.apply(np.array([10.0, 1e4]), np.array([5.0, 0.0]))
    assert np.isfinite(dx[0]) and np.isfinite(dy[0])
    assert np.isnan(dx[1]) and np.isnan(dy[1])


# -- ISIS mission maps ALE writes into ISDs (demtool.sensors.distortion_isis) -------------

MVIC_X = [-2.184e-05, 0.00032911, -2.43e-06, 7.444e-05, -0.00019201, -2.18e-06, 6.86e-06,
          -5.02e-06, -0.0014441, 6.62e-06, -1.94e-06, 5.37e-06, -8.43e-06, 2.01e-06,
          -2.89e-06, -1.53e-06, -2.09e-06, -6.7e-07, -4.9e-06, -0.00012455]
MVIC_Y = [0.0019459, 0.0016936, 1.1e-05, -3.5e-05, 0.0060964, -4.3e-05, 4e-06, -0.002871,
          -0.001149, -5.1e-05, 0.000336, -0.000414, -0.000388, -0.001225, 0.000373, 0.000415,
          4.5e-05, 0.000113, -0.0006, 0.000409]  # the IK's INS-98900_DISTORTION_COEF_X/_Y


def test_legendre_follows_isis_mvic_frame_map():
    """NewHorizonsMvicFrameCameraDistortionMap: x, y negated and scaled to [−1, 1], the
    sum of c_k P_i(x) P_j(y) added; off the detector the point is kept."""
    from numpy.polynomial import legendre as npleg

    from demtool.sensors.distortion_isis import LEGENDRE_TERMS

    half = (32.5, 0.832)  # MVIC: 5000 × 128 pixels of 13 µm
    model = Distortion("legendre", [*half, *MVIC_X, *MVIC_Y])
    x, y = np.array([10.0, -20.0, 31.0]), np.array([0.3, -0.5, 0.8])
    xs, ys = -x / half[0], -y / half[1]

    def p(n, t):
        return npleg.legval(t, [0] * n + [1])

    dx = sum(c * p(i, xs) * p(j, ys) for c, (i, j) in zip(MVIC_X, LEGENDRE_TERMS, strict=True))
    dy = sum(c * p(i, xs) * p(j, ys) for c, (i, j) in zip(MVIC_Y, LEGENDRE_TERMS, strict=True))
    ux, uy = model.remove(x, y)
    np.testing.assert_allclose(ux, -(xs + dx) * half[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(uy, -(ys + dy) * half[1], rtol=0, atol=1e-12)
    back = model.apply(ux, uy)
    np.testing.assert_allclose(back, (x, y), atol=1e-9)
    off = model.remove(np.array([40.0]), np.array([0.1]))  # beyond the 32.5 mm half-width
    np.testing.assert_array_equal(off, ([40.0], [0.1]))


def test_themisir_follows_isis_map():
    """ThemisIrDistortionMap (band 1: k = 0.996005): x_d = k x_u, y_d = y_u (1 + α1) +
    α2 y_u², inverted in closed form."""
    model = Distortion("themisir", [0.00447623, 0.00107556, 0.996005])
    ux, uy = np.array([-3.0, 0.0, 2.5]), np.array([-1.5, 0.2, 3.1])
    dx, dy = model.apply(ux, uy)
    np.testing.assert_allclose(dx, 0.996005 * ux)
    np.testing.assert_allclose(dy, uy * 1.00447623 + 0.00107556 * uy ** 2)
    np.testing.assert_allclose(model.remove(dx, dy), (ux, uy), atol=1e-12)
