"""The compiled line-scan kernel against the numpy model it replaces in ground_to_image."""

from pathlib import Path

import numpy as np
import pytest

from demtool.sensors import read_isd

DATA = Path(__file__).parent / "data"


@pytest.mark.parametrize("name", ["orbitalLineScan", "constVelocityLineScan"])
def test_detector_view_kernel_matches_numpy(name):
    model = read_isd(DATA / f"{name}.json")
    rng = np.random.default_rng(3)
    # Lines inside the image and beyond both ends (extrapolated times: order-2 pieces).
    lines = rng.uniform(-5.0, model.lines + 5.0, 500)
    samples = rng.uniform(0.5, model.samples - 0.5, 500)
    ground = model.image_to_ground(np.clip(lines, 0.5, model.lines - 0.5), samples)
    fast = model._detector_view_fast(lines, ground)
    slow = model._detector_view(lines, ground)
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)


def test_kernel_nan_lines_give_nan():
    model = read_isd(DATA / "orbitalLineScan.json")
    line, sample, depth = model._detector_view_fast(np.array([np.nan, 8.5]),
                                                    model.image_to_ground([8.5, 8.5], [8.0, 8.0]))
    assert np.isnan(line[0]) and np.isnan(sample[0]) and np.isnan(depth[0])
    assert line[1] == pytest.approx(0.0, abs=1e-9) and sample[1] == pytest.approx(8.0, abs=1e-9)
