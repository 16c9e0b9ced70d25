"""An orbital block of frame cameras over a spherical Moon with a reference DEM, for the
ground-control tests (``bundle --reference-dem``) and bench/bundle_reference_dem.py.

Frame cameras at ``altitude`` (default 100 km) in a ``rows × columns`` grid ``spacing``
apart, aimed at the block centre; a field of view ``field_deg`` (Apollo Metric: 74°,
LRO WAC: 60° (monochrome)); hills of ``relief`` metres (7–41 km wavelengths, slopes up
to ~0.3 at 1 km amplitude); tie points on the terrain seen through the true models
with Gaussian noise;
a reference DEM that is the truth sampled at a coarse post spacing with Gaussian
noise (like LOLA gridded products: 100 m–1 km posts, metres of noise).  Everything is
analytic (no rendering), so a test runs in seconds.
"""

from __future__ import annotations

import numpy as np

from demtool.bundle.priors import Observations
from demtool.sensors.base import Detector
from demtool.sensors.frame import FrameSensor
from tests.bundle import frames

RADIUS = 1_737_400.0
CENTRE_LONLAT = (20.0, 10.0)
PIXEL_MM = 0.01


def _unit(lon_deg, lat_deg) -> np.ndarray:
    lon, lat = np.radians(lon_deg), np.radians(lat_deg)
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
                    axis=-1)


def _enu():
    up = _unit(*CENTRE_LONLAT)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    return east, np.cross(up, east), up


def relief(lon_deg, lat_deg, amplitude: float = 1000.0, scale: float = 1.0) -> np.ndarray:
    """Heights (m) above the sphere at planetocentric lon/lat (degrees): three hill
    trains of 7–41 km wavelengths (times ``scale``), ``amplitude`` the sum of their
    amplitudes."""
    east, north, _ = _enu()
    local = _unit(lon_deg, lat_deg) * RADIUS - _unit(*CENTRE_LONLAT) * RADIUS
    x, y = local @ east / scale, local @ north / scale
    return amplitude * (0.45 * np.sin(2 * np.pi * (x / 23e3 + y / 37e3))
                        + 0.35 * np.cos(2 * np.pi * (y / 17e3 - x / 41e3))
                        + 0.20 * np.sin(2 * np.pi * (x + 0.5 * y) / 7e3))


def true_models(*, altitude: float = 100e3, field_deg: float = 60.0, size: int = 1024,
                rows: int = 2, columns: int = 3, spacing: float = 30e3) -> list[FrameSensor]:
    """The true cameras, a ``rows × columns`` grid ``spacing`` metres apart at
    ``altitude``, each aimed at the ground 30 % of the way from below it to the centre."""
    east, north, up = _enu()
    centre = _unit(*CENTRE_LONLAT) * RADIUS
    focal_mm = 0.5 * size * PIXEL_MM / np.tan(np.radians(0.5 * field_deg))
    per_mm = 1.0 / PIXEL_MM
    detector = Detector(itrans_sample=np.array([0.0, per_mm, 0.0]),
                        itrans_line=np.array([0.0, 0.0, per_mm]),
                        center_sample=size / 2, center_line=size / 2)
    models = []
    for k in range(rows * columns):
        row, col = divmod(k, columns)
        offset = (col - (columns - 1) / 2) * spacing * east + \
            (row - (rows - 1) / 2) * spacing * north
        position = centre + altitude * up + offset
        z = centre + 0.7 * offset - position
        z /= np.linalg.norm(z)
        x = np.cross(north, z)
        x /= np.linalg.norm(x)
        rotation = np.stack([x, np.cross(z, x), z], axis=1)
        models.append(FrameSensor(position=position, rotation=rotation,
                                  focal_length=focal_mm, detector=detector, lines=size,
                                  samples=size, radii=(RADIUS, RADIUS), sun=centre * 1e5,
                                  name=f"orbit_{k:02d}"))
    return models


def perturbed(models, *, position_m: float = 50.0, pointing_mrad: float = 0.5,
              seed: int = 1, zero_mean: bool = False) -> list[FrameSensor]:
    """Each model moved by ``position_m`` and turned by ``pointing_mrad`` in random
    directions (independent; ``zero_mean``: pairwise opposite), as
    :func:`tests.bundle.frames.perturbed`."""
    return frames.perturbed(models, position_m=position_m, pointing_mrad=pointing_mrad,
                            seed=seed, zero_mean=zero_mean)


def ground_points(count: int, *, half_width_m: float = 60e3, amplitude: float = 1000.0,
                  scale: float = 1.0, seed: int = 2) -> np.ndarray:
    """(count, 3) body-fixed points on the terrain, uniform over ±``half_width_m``."""
    rng = np.random.default_rng(seed)
    east, north, _ = _enu()
    centre = _unit(*CENTRE_LONLAT) * RADIUS
    flat = centre + rng.uniform(-half_width_m, half_width_m, (count, 1)) * east + \
        rng.uniform(-half_width_m, half_width_m, (count, 1)) * north
    unit = flat / np.linalg.norm(flat, axis=1, keepdims=True)
    lon = np.degrees(np.arctan2(unit[:, 1], unit[:, 0]))
    lat = np.degrees(np.arcsin(unit[:, 2]))
    return unit * (RADIUS + relief(lon, lat, amplitude, scale))[:, None]


def tie_observations(models, xyz, *, noise_px: float = 0.2, seed: int = 3):
    """Observations of ground points ``xyz`` (P, 3) in the models, Gaussian noise;
    points seen by fewer than two images dropped.  Returns (Observations, true points
    in the observations' numbering)."""
    rng = np.random.default_rng(seed)
    image, point, line, sample = [], [], [], []
    for i, m in enumerate(models):
        ln, sm = m.ground_to_image(xyz)
        idx = np.flatnonzero((ln > 0) & (ln < m.lines) & (sm > 0) & (sm < m.samples))
        image.append(np.full(len(idx), i))
        point.append(idx)
        line.append(ln[idx] + rng.normal(0, noise_px, len(idx)))
        sample.append(sm[idx] + rng.normal(0, noise_px, len(idx)))
    obs = Observations(*(np.concatenate(a) for a in (image, point, line, sample)))
    seen = np.flatnonzero(np.bincount(obs.point, minlength=len(xyz)) >= 2)
    return obs.subset(np.ones(len(obs.image), dtype=bool)), xyz[seen]


def reference_dem(*, spacing_m: float = 500.0, noise_m: float = 3.0,
                  half_width_m: float = 90e3, amplitude: float = 1000.0, scale: float = 1.0,
                  seed: int = 4):
    """The terrain on an equirectangular map of the Moon's sphere centred on the block,
    posts ``spacing_m`` apart with Gaussian noise ``noise_m``.

    Returns (heights (H, W) float64, transform, pyproj CRS)."""
    from affine import Affine

    from demtool.maps import body_by_name, lonlat_to_map, make_projection, map_to_lonlat

    crs = make_projection(body_by_name("Moon"), "equirectangular", *CENTRE_LONLAT)
    (cx,), (cy,) = lonlat_to_map(crs, np.array([CENTRE_LONLAT[0]]),
                                 np.array([CENTRE_LONLAT[1]]))
    n = int(np.ceil(2 * half_width_m / spacing_m))
    transform = Affine(spacing_m, 0.0, cx - 0.5 * n * spacing_m, 0.0, -spacing_m,
                       cy + 0.5 * n * spacing_m)
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    lon, lat = map_to_lonlat(crs, transform.c + cols * spacing_m,
                             transform.f - rows * spacing_m)
    rng = np.random.default_rng(seed)
    heights = relief(lon, lat, amplitude, scale) + rng.normal(0.0, noise_m, lon.shape)
    return heights, transform, crs
