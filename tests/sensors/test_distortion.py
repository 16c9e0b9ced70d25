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
