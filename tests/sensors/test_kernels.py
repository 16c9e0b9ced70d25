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


def _ray_angle(a, b):
    """Angle (rad) between unit vectors, accurate for tiny angles."""
    return 2 * np.arcsin(np.clip(0.5 * np.linalg.norm(a - b, axis=-1), 0, 1))


def _synthetic_linescan():
    from demtool.sensors import Distortion
    from tests.helpers.linescan import linescan_sensor

    model = linescan_sensor(lines=400, samples=300, roll_deg=15.0)
    # A strong radial distortion so the undistorted focal-plane points are not trivial.
    model.distortion = Distortion("radial", [1e-5, 2e-8, 0.0], model.focal_length)
    return model


@pytest.mark.parametrize("name", ["orbitalLineScan", "constVelocityLineScan", "synthetic"])
def test_image_rays_kernel_matches_numpy(name):
    model = (_synthetic_linescan() if name == "synthetic"
             else read_isd(DATA / f"{name}.json"))
    model.coverage = None  # compared beyond the sampled ephemeris too (no masking)
    rng = np.random.default_rng(5)
    # Lines inside and beyond both ends (extrapolated, order-2 pieces), a 2-D shape.
    lines = rng.uniform(-5.0, model.lines + 5.0, (40, 25))
    samples = rng.uniform(0.5, model.samples - 0.5, (40, 25))
    fast = model.image_to_ray(lines, samples)
    slow = model._image_to_ray_numpy(lines, samples)
    assert fast.origin.shape == fast.direction.shape == (40, 25, 3)
    assert np.abs(fast.origin - slow.origin).max() <= 1e-9
    assert _ray_angle(fast.direction, slow.direction).max() <= 1e-12
    np.testing.assert_allclose(np.linalg.norm(fast.direction, axis=-1), 1.0, atol=1e-14)
    # Broadcasting a scalar line against samples, and a NaN line giving NaN rays.
    ray = model.image_to_ray(np.array([np.nan, 3.5]), 7.5)
    assert np.isnan(ray.origin[0]).all() and np.isnan(ray.direction[0]).all()
    ref = model._image_to_ray_numpy(3.5, 7.5)
    assert np.abs(ray.origin[1] - ref.origin).max() <= 1e-9
    assert _ray_angle(ray.direction[1], ref.direction) <= 1e-12


def test_kernels_in_parts_are_the_one_thread_values(monkeypatch):
    from tests.helpers.row_parts import whole_and_split

    model = read_isd(DATA / "orbitalLineScan.json")
    rng = np.random.default_rng(5)
    lines = rng.uniform(0.5, model.lines - 0.5, 400)
    samples = rng.uniform(0.5, model.samples - 0.5, 400)
    lines[7] = np.nan
    ground = model.image_to_ground(np.nan_to_num(lines, nan=8.5), samples)

    def compute():
        ray = model.image_to_ray(lines, samples)
        return (ray.origin, ray.direction, *model._detector_view_fast(lines, ground))

    whole, split, seen = whole_and_split(monkeypatch, compute)
    assert len(seen) == 2 and all(len(parts) == 3 for parts in seen)
    for a, b in zip(whole, split, strict=True):
        np.testing.assert_array_equal(a, b)
