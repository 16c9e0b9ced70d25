"""Where a camera is and what it sees of its body: the checks of
:mod:`demtool.sensors.validate` that must refuse only the impossible.

- **Inside the body.**  A camera below the reference ellipsoid is normal on a planet's
  surface (a rover in Gale crater sits ~4.5 km below the Mars datum; the Moon's surface
  spans −9.1 … +10.8 km).  A camera is impossible only deeper than the body's lowest
  surface (:data:`RELIEF_KM`, widened by :data:`RELIEF_MARGIN` for the datum's
  departure from the ellipsoid); for small irregular bodies, whose shape is not the
  ellipsoid, only deeper than :data:`IRREGULAR_DEPTH` of the mean radius.  Positions in
  km labelled metres put the camera at 1/1000 of its distance from the centre, far deeper
  than any relief.
- **A surface camera.**  A camera within the relief band (below the highest surface
  plus :data:`SURFACE_CLEARANCE_M`) is a rover's or lander's: it loads, and is named so.
- **The view.**  Judged on a dense grid of rays (:data:`VIEW_GRID` × :data:`VIEW_GRID`
  over the image, edges included): the fraction that meets the body is reported (a limb
  image loads).  When no grid ray meets it, the body's centre and the point of its
  ellipsoid nearest the camera are projected into the image: a body smaller than the
  grid spacing is still in view.  A camera that sees no surface at all is reported,
  not refused, where the caller allows it (``demtool camera``); stages that need
  ground refuse it.

Relief (lowest, highest surface against the reference ellipsoid / datum): Mars
−8.2 … +21.2 km (MOLA: Hellas, Olympus Mons), the Moon −9.1 … +10.8 km (LOLA), Mercury
−5.4 … +4.5 km (MESSENGER MLA), Venus −2.9 … +11.0 km (Magellan), Earth −11.0 … +8.8 km
(the Mariana Trench, Everest).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: name: (semi-major axis km, lowest km, highest km) of bodies with measured relief.
RELIEF_KM = {
    "Mars": (3396.19, -8.2, 21.2),
    "Moon": (1737.4, -9.1, 10.8),
    "Mercury": (2439.4, -5.4, 4.5),
    "Venus": (6051.8, -2.9, 11.0),
    "Earth": (6378.137, -11.0, 8.8),
}
#: a body of this table is recognised by a semi-major axis within this fraction.
RADIUS_MATCH = 0.02
#: the lowest surface widened by this fraction (datum vs ellipsoid, kernel generations).
RELIEF_MARGIN = 0.25
#: bodies not in the table with a mean radius above this (km) are taken as round, with
#: relief up to :data:`ROUND_RELIEF` of the radius (Vesta's ±22 km is 8 %).
ROUND_BODY_KM = 1000.0
ROUND_RELIEF = 0.02
#: smaller bodies are irregular: a camera is inside only below this fraction of the
#: mean radius from the centre's side of the ellipsoid.
IRREGULAR_DEPTH = 0.5
#: a camera lower than the highest surface plus this is a surface camera.
SURFACE_CLEARANCE_M = 1000.0
#: a surface camera's view is judged against the ellipsoid raised to this far below the
#: camera (a rover's mast, a lander's deck: the local ground).
SURFACE_GROUND_M = 2.0
#: rays per image side of the view grid.
VIEW_GRID = 33


class Band(NamedTuple):
    """Heights (metres above the reference ellipsoid) a camera may have on the surface."""

    low: float
    high: float
    label: str


def relief_band(a: float, b: float) -> Band:
    """The lowest height a camera may have (metres; below it the camera is inside the
    body) and the highest surface, for a body of semi-axes ``a``, ``b`` (metres)."""
    for name, (radius_km, low, high) in RELIEF_KM.items():
        if abs(a / 1000.0 - radius_km) <= RADIUS_MATCH * radius_km:
            return Band((1.0 + RELIEF_MARGIN) * low * 1000.0, high * 1000.0,
                        f"{name}'s relief ({low:+g} … {high:+g} km)")
    mean = (2.0 * a + b) / 3.0
    if mean >= ROUND_BODY_KM * 1000.0:
        return Band(-ROUND_RELIEF * mean, ROUND_RELIEF * mean,
                    f"relief of {100 * ROUND_RELIEF:g} % of the mean radius")
    return Band(-IRREGULAR_DEPTH * mean, 0.1 * mean,
                f"a small irregular body (down to {100 * IRREGULAR_DEPTH:g} % of its mean "
                "radius)")


def height_above_ellipsoid(xyz, a: float, b: float) -> np.ndarray:
    """Height (metres) of points above the ellipsoid along their direction from the
    centre (negative inside); S + (3,) → S."""
    xyz = np.asarray(xyz, dtype=np.float64)
    r = np.linalg.norm(xyz, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = xyz / r[..., None]
        r_surface = 1.0 / np.sqrt((u[..., 0] ** 2 + u[..., 1] ** 2) / a ** 2
                                  + u[..., 2] ** 2 / b ** 2)
    return np.where(r > 0, r - r_surface, -min(a, b))


class View(NamedTuple):
    """What a model sees of its body (see the module docstring)."""

    fraction: float      # of the ray grid meeting the body
    boresight: bool      # the image centre's ray meets it
    in_view: bool        # some part of the body is in the image
    where: str           # words for a note or message


def image_grid(lines: int, samples: int, n: int = VIEW_GRID) -> tuple[np.ndarray, np.ndarray]:
    """An ``n × n`` grid of image points from edge to edge (CSM coordinates)."""
    return np.meshgrid(np.linspace(0.0, float(lines), n), np.linspace(0.0, float(samples), n),
                       indexing="ij")


def body_view(model, n: int = VIEW_GRID, height: float = 0.0) -> View:
    """Fraction of an ``n × n`` ray grid meeting the ellipsoid raised by ``height``
    (metres; a surface camera's local ground), and whether the body is in view at all
    (its centre or its point nearest the camera projecting into the image)."""
    from demtool.sensors.base import ray_ellipsoid_intersection

    a, b = (float(v) for v in model.radii)
    lines, samples = int(model.lines), int(model.samples)
    ll, ss = image_grid(lines, samples, n)
    with np.errstate(all="ignore"):
        ray = model.image_to_ray(ll, ss)
        _, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, a, b, height,
                                            return_hit=True)
        centre_ray = model.image_to_ray(np.array([0.5 * lines]), np.array([0.5 * samples]))
        _, centre_hit = ray_ellipsoid_intersection(centre_ray.origin, centre_ray.direction,
                                                   a, b, height, return_hit=True)
    hit &= np.all(np.isfinite(ray.direction), axis=-1)
    fraction = float(np.mean(hit))
    if fraction > 0:
        return View(fraction, bool(centre_hit[0]), True,
                    f"{100 * fraction:.3g} % of a {n}×{n} ray grid meets the body")
    origin = np.asarray(centre_ray.origin, dtype=np.float64).reshape(3)
    targets = [np.zeros(3)]
    if np.all(np.isfinite(origin)) and np.linalg.norm(origin) > 0:
        targets.append(origin * (a / np.linalg.norm(origin)))
    for target in targets:
        try:
            with np.errstate(all="ignore"):
                line, sample = model.ground_to_image(target)
        except (ValueError, ArithmeticError):
            continue
        line, sample = float(np.asarray(line).reshape(-1)[0]), float(
            np.asarray(sample).reshape(-1)[0])
        if 0.0 <= line <= lines and 0.0 <= sample <= samples:
            return View(0.0, False, True,
                        f"the body is in view but smaller than the {n}×{n} ray grid's "
                        f"spacing (seen near line {line:.1f}, sample {sample:.1f})")
    return View(0.0, False, False, f"no ray of a {n}×{n} grid over the image meets the body "
                "and its centre projects outside the image")


def reference_height(model) -> float:
    """Height (metres above the ellipsoid) of the ground a model's rays are judged on:
    0 for an orbital camera, :data:`SURFACE_GROUND_M` below the camera for a surface
    camera (``model.surface_camera``, set by :mod:`demtool.sensors.validate`)."""
    if not getattr(model, "surface_camera", False):
        return 0.0
    a, b = (float(v) for v in model.radii)
    centre = np.asarray(model.camera_center(np.array([0.5 * model.lines])), dtype=np.float64)
    return float(np.nanmedian(height_above_ellipsoid(centre, a, b))) - SURFACE_GROUND_M
