"""The synthetic scene: parameters, camera layout, and :func:`make_scene`.

Geometry (world frame of CONTRIBUTING.md: X east, Y north, Z up, metres, origin at
the scene centre, Z = 0 the mean surface).  Every camera flies at ``altitude_m``
above the mean surface and looks at the scene centre with the same focal length:

* ``view_00``, the target, is exactly nadir above the centre with image up = north,
  so image right = east and image down = south (its grid frame is the world frame);
* ``view_01``, the stereo partner, is displaced east by ``partner_bh · altitude``
  (baseline along image x, so rectification is gentle);
* ``view_02`` … have base-to-height ratios (to the target) spread evenly from
  ``bh_min`` to ``bh_max`` at azimuths a golden angle apart.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from demtool.errors import ParameterError
from demtool.imaging.reflectance import lunar_lambert, sun_vector
from demtool.logs import get_logger
from demtool.sensors.pinhole import PinholeCamera, look_at
from demtool.synth import render, terrain
from demtool.synth.params import SceneParams

log = get_logger(__name__)

GOLDEN_ANGLE_DEG = 180.0 * (3.0 - np.sqrt(5.0))  # 137.5°
FOOTPRINT_MARGIN = 0.04  # fraction of the DEM side kept free around every footprint


@dataclass(frozen=True)
class Scene:
    """A rendered synthetic scene (see :func:`make_scene`).

    Attributes
    ----------
    params : SceneParams
    dem : (N, N) float32
        Truth heights on the map grid, metres above the mean surface (mean 0).
    dem_transform : affine.Affine
        ``Affine(s, 0, −N s/2, 0, −s, N s/2)``: map grid centred on the world origin.
    albedo : (N, N) float32
        Normal albedo on the map grid.
    names : tuple of str
        View names ``view_00`` … in order; ``target`` and ``partner`` are two of them.
    cameras : dict of str to PinholeCamera
        The local-frame pinholes (``pinhole`` and ``frame`` scenes; empty for
        ``linescan``).
    images : dict of str to (h, w) float32
        Digital numbers 0 … 2^bit_depth − 1 (integer-valued), NaN where a ray missed.
    depths : dict of str to (h, w) float64
        Camera z of each pixel's hit (metres), NaN where the ray missed.
    shadows : dict of str to (h, w) bool
        Shadow mask of each view: no direct sunlight (attached or cast shadow).
    truth_target : (h, w) float32
        World Z of the target pixels' hits, metres above the mean surface.
    sun_vector : (3,) float64
        Unit vector toward the sun, world frame.
    gsd_m : float
        Ground sampling distance of the target at Z = 0, metres per pixel.
    distance_m : float
        Target camera to the mean surface (= altitude), metres.
    dn_per_reflectance : float
        Expected DN per unit of lunar-Lambert reflectance (before noise).
    render_time_s : float
        Wall time of :func:`make_scene`, seconds.
    timings : dict of str to float
        Seconds per step (terrain, each view).
    sensor : str
        ``pinhole``, ``frame`` or ``linescan`` (:data:`demtool.synth.params.SENSORS`).
    placement : demtool.synth.body.Placement or None
        The local frame on the body (``frame``, ``linescan``).
    sensors : dict of str to SensorModel
        The body-fixed models the views were rendered through (``frame``,
        ``linescan``); empty for ``pinhole`` (rendered through ``cameras``).
    """

    params: SceneParams
    dem: np.ndarray
    dem_transform: Any
    albedo: np.ndarray
    names: tuple[str, ...]
    target: str
    partner: str
    cameras: dict[str, PinholeCamera]
    images: dict[str, np.ndarray]
    depths: dict[str, np.ndarray]
    shadows: dict[str, np.ndarray]
    truth_target: np.ndarray
    sun_vector: np.ndarray
    gsd_m: float
    distance_m: float
    dn_per_reflectance: float
    render_time_s: float
    timings: dict[str, float] = field(default_factory=dict)
    sensor: str = "pinhole"
    placement: Any = None
    sensors: dict[str, Any] = field(default_factory=dict)


def view_name(index: int) -> str:
    """``view_00``, ``view_01``, …"""
    return f"view_{index:02d}"


def dem_transform(params: SceneParams):
    """Map-grid transform of the scene's DEM, centred on the world origin."""
    from affine import Affine

    half = 0.5 * params.dem_size * params.spacing_m
    return Affine(params.spacing_m, 0.0, -half, 0.0, -params.spacing_m, half)


def camera_positions(params: SceneParams) -> np.ndarray:
    """Camera centres (n_views, 3), world metres: target, partner, then the others
    (``layout`` "stereo"), or the ring or strip of :class:`SceneParams`."""
    h = params.altitude_m
    if params.layout == "ring":
        azimuth = np.radians(360.0 * np.arange(params.n_views) / params.n_views)
        radius = params.bh_max * h
        return np.column_stack([radius * np.sin(azimuth), radius * np.cos(azimuth),
                                np.full(params.n_views, h)])
    if params.layout == "strip":
        x = (np.arange(params.n_views) - 0.5 * (params.n_views - 1)) * params.partner_bh * h
        return np.column_stack([x, np.zeros_like(x), np.full(params.n_views, h)])
    positions = [(0.0, 0.0, h), (params.partner_bh * h, 0.0, h)]
    others = params.n_views - 2
    ratios = np.linspace(params.bh_min, params.bh_max, others) if others > 1 else \
        np.array([0.5 * (params.bh_min + params.bh_max)])[:others]
    for k, ratio in enumerate(ratios):
        azimuth = np.radians(30.0 + k * GOLDEN_ANGLE_DEG)  # clockwise from north
        positions.append((ratio * h * np.sin(azimuth), ratio * h * np.cos(azimuth), h))
    return np.asarray(positions, dtype=np.float64)


def make_cameras(params: SceneParams) -> dict[str, PinholeCamera]:
    """The scene's cameras by name, all looking at the scene centre (module docstring)."""
    focal = params.altitude_m / params.gsd_m
    cameras = {}
    for i, centre in enumerate(camera_positions(params)):
        aim = (centre[0], centre[1], 0.0) if params.layout == "strip" else (0.0, 0.0, 0.0)
        camera = look_at(centre, aim, (0.0, 1.0, 0.0), focal_px=focal,
                         width=params.image_size, height=params.image_size)
        if params.cx_offset_px or params.cy_offset_px:
            K = camera.K.copy()
            K[0, 2] += params.cx_offset_px
            K[1, 2] += params.cy_offset_px
            camera = PinholeCamera(K=K, R=camera.R, t=camera.t, width=camera.width,
                                   height=camera.height)
        cameras[view_name(i)] = camera
    return cameras


def footprint_bounds(camera, z_min: float, z_max: float, *, placement=None) -> np.ndarray:
    """(x_min, x_max, y_min, y_max) of the ground any pixel can see between z_min and z_max.

    A pinhole's rays fill a pyramid; its part between the two planes is a convex
    frustum whose corners are the corner rays' crossings of the planes, so these
    bound every possible hit exactly.  Other sensor models (``placement`` given for
    body-fixed ones) are bounded by rays along the whole image border
    (:func:`demtool.synth.sensors.footprint_bounds`).
    """
    from demtool.synth.sensors import footprint_bounds as bounds

    step = max(camera.lines, camera.samples) if isinstance(camera, PinholeCamera) else 1
    return bounds(camera, z_min, z_max, placement=placement, border_step=step)


def check_footprints(params: SceneParams, cameras: dict[str, Any], z_min: float,
                     z_max: float, *, placement=None) -> None:
    """Raise ParameterError when a view can see beyond the DEM (with a margin).

    Every hit of every view must lie at least ``FOOTPRINT_MARGIN`` of the DEM side
    inside its edges, so rays never miss and the terrain casting shadows into the
    views is modelled.
    """
    label = params.label
    half = 0.5 * params.dem_size * params.spacing_m
    limit = half * (1.0 - 2.0 * FOOTPRINT_MARGIN)
    if z_max >= params.altitude_m:
        params.fail("altitude_m", f"({params.altitude_m}) must be above the highest terrain "
                                  f"({z_max:.1f} m)")
    for name, camera in cameras.items():
        x0, x1, y0, y1 = footprint_bounds(camera, z_min, z_max, placement=placement)
        reach = max(abs(x0), abs(x1), abs(y0), abs(y1))
        if reach > limit:
            raise ParameterError(
                f"{name} sees ground up to {reach:.1f} m from the centre, but the DEM "
                f"({label('dem_size')} {params.dem_size} × {label('spacing_m')} "
                f"{params.spacing_m}) keeps only ±{limit:.1f} m with its margin; use a larger "
                f"{label('dem_size')} or {label('spacing_m')}, a smaller {label('gsd_m')} or "
                f"{label('image_size')}, or smaller B/H ratios ({label('partner_bh')}, "
                f"{label('bh_max')})")


def make_sensors(params: SceneParams, cameras: dict[str, PinholeCamera], sun: np.ndarray
                 ) -> tuple[Any, dict[str, Any]]:
    """The body placement and the body-fixed sensor models of a ``frame`` or ``linescan``
    scene (:mod:`demtool.synth.sensors`): the pinholes as frame cameras, or the line-scan
    pair (``view_00`` rolled west-looking by half the convergence, ``view_01`` east).

    Raises
    ------
    ParameterError
        Unknown body (naming ``--body``).
    """
    from demtool.synth import sensors as synth_sensors
    from demtool.synth.body import placement

    try:
        place = placement(params.body, params.center_lon_deg, params.center_lat_deg)
    except ValueError as exc:
        params.fail("body", str(exc))
    sun_position = place.sun_position(sun)
    if params.sensor == "frame":
        return place, {name: synth_sensors.frame_sensor(camera, place, sun_position=sun_position,
                                                        name=name)
                       for name, camera in cameras.items()}
    half = 0.5 * params.convergence_deg
    return place, {view_name(i): synth_sensors.linescan_sensor(
        place, off_nadir_deg=roll, altitude_m=params.altitude_m, gsd_m=params.gsd_m,
        ground_speed_m_s=params.ground_speed_m_s, lines=params.lines,
        samples=params.image_size, sun_position=sun_position, name=view_name(i))
        for i, roll in enumerate((-half, half))}


def flat_dn_per_reflectance(params: SceneParams) -> float:
    """DN per unit reflectance so a flat mean-albedo surface at nadir gives ``exposure_dn``.

    Flat surface: μ0 = cos i, μ = 1, phase α = i, so
    ``R = ρ (2L μ0 / (μ0 + 1) + (1 − L) μ0)`` (McEwen 1991, eq. 4).
    """
    mu0 = np.cos(np.radians(params.sun_incidence_deg))
    flat = float(lunar_lambert(mu0, 1.0, params.sun_incidence_deg, params.albedo_mean))
    return params.exposure_dn / flat


def make_terrain(params: SceneParams) -> tuple[np.ndarray, np.ndarray]:
    """The truth DEM (metres, mean 0) and albedo on the map grid, both (N, N) float64."""
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(params.seed).spawn(4)]
    n, s = params.dem_size, params.spacing_m
    dem = terrain.fractal_surface(n, s, spectral_exponent=params.spectral_exponent,
                                  rms_m=params.fractal_rms_m, rng=streams[0])
    if params.crater_count:
        diameters = terrain.crater_diameters(
            params.crater_count, min_diameter_m=params.crater_min_diameter_m,
            max_diameter_m=params.crater_max_diameter_m, exponent=params.crater_exponent,
            rng=streams[1])
        dem = terrain.add_craters(dem, s, diameters, depth_ratio=params.crater_depth_ratio,
                                  rim_ratio=params.rim_height_ratio, rng=streams[1])
    if params.boulder_count:
        dem = terrain.add_boulders(dem, s, params.boulder_count,
                                   mean_height_m=params.boulder_height_m, rng=streams[2])
    dem = dem - dem.mean()
    albedo = terrain.albedo_map(n, s, mean=params.albedo_mean, variation=params.albedo_variation,
                                correlation_m=params.albedo_correlation_m, rng=streams[3])
    return dem, albedo


def render_view(field, albedo: np.ndarray, camera, sun: np.ndarray, *, placement, name: str,
                params: SceneParams, dn_per_reflectance: float, rng: np.random.Generator,
                heights: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, Any]:
    """Render one view in blocks of rows (:func:`demtool.synth.render.row_blocks`).

    Returns the image ((h, w) float32 DN), the depth ((h, w) float64), the shadow mask
    ((h, w) bool) and, when ``heights``, the world Z of the hits ((h, w) float32; else
    None).  An image of one block is exposed in one draw of ``rng``; larger ones draw
    block after block (the same seed gives the same image).

    Raises
    ------
    ParameterError
        Rays that miss the DEM (excluded by :func:`check_footprints`; a safeguard).
    """
    lines, samples = camera.lines, camera.samples
    image = np.empty((lines, samples), dtype=np.float32)
    depth = np.empty((lines, samples))
    shadow = np.empty((lines, samples), dtype=bool)
    hit_z = np.empty((lines, samples), dtype=np.float32) if heights else None
    for first, stop in render.row_blocks(lines, samples):
        geometry = render.view_geometry(field, albedo, camera, sun, placement=placement,
                                        rows=(first, stop))
        if np.isnan(geometry.depth).any():
            raise ParameterError(f"{name}: {int(np.isnan(geometry.depth).sum())} rays miss "
                                 f"the DEM; enlarge dem_size")
        image[first:stop] = render.expose(
            render.reflectance(geometry), dn_per_reflectance=dn_per_reflectance,
            gain_e_per_dn=params.gain_e_per_dn, read_noise_dn=params.read_noise_dn,
            bit_depth=params.bit_depth, noise=params.noise, rng=rng)
        depth[first:stop] = geometry.depth
        shadow[first:stop] = geometry.shadow
        if hit_z is not None:
            hit_z[first:stop] = geometry.hit[:, :, 2]
    return image, depth, shadow, hit_z


def make_scene(params: SceneParams | None = None, *, dem: np.ndarray | None = None,
               albedo: np.ndarray | None = None, sensor_models=None) -> Scene:
    """Build and render a synthetic scene.

    Parameters
    ----------
    params : SceneParams, optional
        Defaults to ``SceneParams()`` (the demo scene).
    dem : (N, N) float, optional
        Use this truth DEM (metres, map grid, N = ``params.dem_size``) instead of
        generating one: for tests with known shapes (planes, ridges).  Used as given
        (not re-centred).
    albedo : (N, N) float, optional
        Use this albedo map instead of generating one.
    sensor_models : (Placement, dict), optional
        Render through these body-fixed models at this placement instead of the
        synthetic views (``synth --sensor-model``, :mod:`demtool.synth.real`).

    Returns
    -------
    Scene

    Raises
    ------
    ParameterError
        Invalid parameters, or a view that would see beyond the DEM.
    """
    params = params or SceneParams()
    params.check()
    started = time.perf_counter()
    timings: dict[str, float] = {}
    generated_dem, generated_albedo = make_terrain(params) if dem is None or albedo is None \
        else (None, None)
    shape = (params.dem_size, params.dem_size)
    for name, given in (("dem", dem), ("albedo", albedo)):
        if given is not None and np.shape(given) != shape:
            raise ParameterError(f"{name} has shape {np.shape(given)}, expected {shape} "
                                 f"(dem_size)")
    # Render from the float32 values that are written to disk, so files and images agree.
    dem = (generated_dem if dem is None else np.asarray(dem)).astype(np.float32)
    albedo = (generated_albedo if albedo is None else np.asarray(albedo)).astype(np.float32)
    del generated_dem, generated_albedo
    transform = dem_transform(params)
    field = render.height_field(dem.astype(np.float64), transform)
    timings["terrain"] = time.perf_counter() - started
    log.debug("terrain: %d × %d cells, heights %.1f … %.1f m", *shape, dem.min(), dem.max())

    sun = sun_vector(params.sun_incidence_deg, params.sun_azimuth_deg)
    if sensor_models is not None:  # real geometries (demtool.synth.real)
        cameras, (place, sensors) = {}, sensor_models
    else:
        cameras = make_cameras(params) if params.sensor != "linescan" else {}
        place, sensors = None, {}
        if params.sensor != "pinhole":
            place, sensors = make_sensors(params, cameras, sun)
    views = sensors or cameras
    check_footprints(params, views, field.z_min, field.z_max, placement=place)
    dn_scale = flat_dn_per_reflectance(params)
    noise_seeds = np.random.SeedSequence([params.seed, 1]).spawn(len(views))
    images, depths, shadows = {}, {}, {}
    truth_target = None
    albedo64 = albedo.astype(np.float64)
    for index, (name, camera) in enumerate(views.items()):
        step_start = time.perf_counter()
        image, depth, shadow, heights = render_view(
            field, albedo64, camera, sun, placement=place, name=name, params=params,
            dn_per_reflectance=dn_scale, rng=np.random.default_rng(noise_seeds[index]),
            heights=index == 0)
        images[name], depths[name], shadows[name] = image, depth, shadow
        if index == 0:
            truth_target = heights
        timings[name] = time.perf_counter() - step_start
        log.info("%s rendered in %.2f s (%.1f %% in shadow)", name, timings[name],
                 100.0 * shadow.mean())
    names = tuple(views)
    return Scene(params=params, dem=dem, dem_transform=transform,
                 albedo=albedo, names=names, target=names[0],
                 partner=names[1], cameras=cameras, images=images, depths=depths,
                 shadows=shadows, truth_target=truth_target, sun_vector=sun,
                 gsd_m=params.gsd_m, distance_m=params.altitude_m,
                 dn_per_reflectance=dn_scale, render_time_s=time.perf_counter() - started,
                 timings=timings, sensor=params.sensor, placement=place, sensors=sensors)
