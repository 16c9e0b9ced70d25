"""A synthetic block of three line scanners on the Moon measured by a control network,
with a known pointing error of each prior model (angles and rates), for the
``bundle --control-network`` tests and bench/control_network.py.

The true models are :func:`tests.helpers.linescan.linescan_sensor` rolled −12°, 0°, +12°
(1 m pixels, 300 × 200); the prior models are the true ones turned by ``bias`` (per
image: omega, phi, kappa in rad, their rates in rad/s, :mod:`demtool.bundle.network`'s
parameters), so the adjustment should find ``−bias``.  The points are on the analytic
terrain, measured through the true models with Gaussian noise; some can be fixed (ground
control) to pin the block's datum.
"""

from __future__ import annotations

import numpy as np

from demtool.bundle.network import image_axes
from demtool.bundle.network_models import CorrectedSensor, adjust_isd_timed
from demtool.io.controlnet import ControlMeasure, ControlNetwork, ControlPoint
from demtool.maps import lonlat_height_to_xyz
from tests.helpers.linescan import R, isd_dict, linescan_sensor, terrain

ROLLS = (-12.0, 0.0, 12.0)
CENTRE_TIMES = (1000.0, 5000.0, 9000.0)
#: a mission clock: seconds since an epoch 630 Ms before J2000 (like MRO's)
CLOCK_EPOCH = 630_000_000.0


def true_models():
    """The three true models, each orbit moved across track so that its image centre
    sees (10° E, 5° N)."""
    from demtool.maps import xyz_to_lonlat_height

    models = []
    for k, roll in enumerate(ROLLS):
        lon0 = 10.0
        for _ in range(3):
            model = linescan_sensor(lines=300, samples=200, gsd=10.0, roll_deg=roll, lon0=lon0,
                                    name=f"img{k}")
            lon, _, _ = xyz_to_lonlat_height(model.image_to_ground(150.0, 100.0), radii=R)
            lon0 += 10.0 - float(lon)
        models.append(model)
    return models


def bias(seed: int = 4, angle_rad: float = 2e-4, rate_rad_s: float = 4e-5) -> np.ndarray:
    """(3, 12) pointing errors of the prior models (angles and rates only)."""
    rng = np.random.default_rng(seed)
    theta = np.zeros((3, 12))
    theta[:, 0:3] = rng.normal(0.0, angle_rad, (3, 3))
    theta[:, 3:6] = rng.normal(0.0, rate_rad_s, (3, 3))
    return theta


def prior_models(models, theta):
    return [CorrectedSensor(m, image_axes(m), t) for m, t in zip(models, theta, strict=True)]


def prior_isds(models, theta) -> list[dict]:
    """ISDs of the prior models (the true ones with ``theta`` applied)."""
    out = []
    for model, t, centre in zip(models, theta, CENTRE_TIMES, strict=True):
        isd = isd_dict(model, center_time=centre)
        out.append(adjust_isd_timed(isd, image_axes(model), t, center_time=centre))
    return out


def serial(k: int, model) -> str:
    start = CENTRE_TIMES[k] + float(model.line_time(0.0))
    return f"SYN/LS/{int(CLOCK_EPOCH + start):010d}:{k * 17:03d}"


def network(models, *, count: int = 60, noise_px: float = 0.1, fixed: int = 0,
            seed: int = 5) -> tuple[ControlNetwork, np.ndarray]:
    """A control network of ``count`` points seen by all three true models (ISIS pixel
    convention handled by the writer) and the points' true positions (P, 3)."""
    from tests.helpers.linescan import MOON  # noqa: F401  (the body of the scene)

    rng = np.random.default_rng(seed)
    lon = 10.0 + rng.uniform(-0.9, 0.9, count) * 600.0 / (R * np.radians(1.0))
    lat = 5.0 + rng.uniform(-0.9, 0.9, count) * 1000.0 / (R * np.radians(1.0))
    xyz = lonlat_height_to_xyz(lon, lat, terrain(lon, lat), radii=R)
    seen = [model.ground_to_image(xyz) for model in models]  # (line, sample) per model
    points = []
    for j in range(count):
        measures = [ControlMeasure(serial(k, model), "RegisteredSubPixel",
                                   line=float(seen[k][0][j]) + rng.normal(0, noise_px),
                                   sample=float(seen[k][1][j]) + rng.normal(0, noise_px))
                    for k, model in enumerate(models)]
        kind = "Fixed" if j < fixed else "Free"
        points.append(ControlPoint(f"p{j:03d}", kind, measures,
                                   apriori_xyz=xyz[j].copy() if j < fixed else None))
    return ControlNetwork("SYNTHETIC", "Moon", points, user_name="test"), xyz
