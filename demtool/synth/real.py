"""Synthetic terrain seen through two real camera models (``synth --sensor-model L R``).

The HiRISE study's evaluation (errors of geometry and of matching told apart): a
synthetic terrain with known truth is placed on the body under the common footprint of
two real sensor models (any two frame or line-scan models demtool reads: ISDs, ISIS
cubes, .tsai on a body), and rendered through *windows* of those real geometries, so
that a DEM made from the pair can be compared with the truth on the map.

- the scene centre is the centre of the two footprints' intersection
  (:func:`demtool.camera.info.pair_geometry`), on the body's reference sphere;
- each model is cut to a window of ``image_lines`` × ``image_size`` pixels (lines ×
  samples; ``image_lines`` 0: square) centred on the image of the scene centre, or
  moved inside the image where a centred window would leave it (a full-width window)
  (:func:`window`: the same camera with its detector origin and line timing shifted;
  the windows' origins are logged, and the windows' ISDs are written beside the
  images);
- the DEM cell is half the finer window's ground sampling distance and the DEM 15 %
  larger than both windows' reach on the sphere, plus the renderer's margin (logged);
  windows that would need more than :data:`MAX_DEM_SIZE` cells a side get coarser
  cells instead (a full NAC width of 12 000 lines: about 3.7 pixels a cell), so
  the terrain is smoother than the images' pixels there;
  ``--gsd`` becomes the coarser window's GSD, the spacing of ``truth_dem_map.tif``.

Push-frame windows hold whole framelets (their line count rounded to the framelet
height).  RPC models are refused (an RPC carries no sensor position for the renderer).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from demtool.errors import InputError
from demtool.sensors import FrameSensor, LineScanSensor, PushFrameSensor


def window(model, line0: int, sample0: int, lines: int, samples: int):
    """The same camera restricted to image rows ``line0 …`` and columns ``sample0 …``.

    A frame model's detector origin moves by the window offset (times its summing); a
    line-scan model's line-rate table moves by ``line0`` lines and its detector start by
    ``sample0`` samples.  Pixel (l, s) of the window is pixel (l + line0, s + sample0) of
    the model.
    """
    detector = model.detector._replace(
        start_sample=model.detector.start_sample + sample0 * model.detector.sample_summing)
    if isinstance(model, FrameSensor) and type(model) is FrameSensor:
        detector = detector._replace(
            start_line=model.detector.start_line + line0 * model.detector.line_summing)
        return FrameSensor(position=model.position, rotation=model.rotation,
                           focal_length=model.focal_length, detector=detector,
                           distortion=model.distortion, lines=lines, samples=samples,
                           radii=model.radii, sun=model.sun, name=model.name,
                           time=model.time, z_direction=model.z_direction)
    if getattr(model, "kind", "") == "pushframe":
        return _pushframe_window(model, line0, detector, lines, samples)
    if type(model) is LineScanSensor:
        rate = np.column_stack([model.int_lines - line0, model.int_start_times,
                                model.int_times])
        out = LineScanSensor(
            line_scan_rate=rate, positions=model.positions, t0_ephem=model.t0_ephem,
            dt_ephem=model.dt_ephem, quaternions=model.quaternions, t0_quat=model.t0_quat,
            dt_quat=model.dt_quat, focal_length=model.focal_length, detector=detector,
            distortion=model.distortion, lines=lines, samples=samples, radii=model.radii,
            sun_positions=model.sun_positions, sun_velocities=model.sun_velocities,
            velocities=model.velocities, name=model.name, center_time=model.center_time)
        out.coverage = model.coverage
        return out
    raise ValueError(f"a {model.kind or type(model).__name__} model cannot be cut to a window "
                     "(frame and line-scan models only)")


def _pushframe_window(model, line0: int, detector, lines: int, samples: int):
    """A push-frame window: whole framelets only (``line0`` and ``lines`` multiples of
    the summed framelet height), the start time moved by the framelets skipped (counted
    from the end when the framelet order is reversed)."""
    from demtool.sensors.pushframe import PushFrameSensor

    h = model.summed_height
    if line0 % h or lines % h:
        raise ValueError(f"a push-frame window must hold whole framelets: line {line0} and "
                         f"{lines} lines are not multiples of {h}")
    skipped = (model.n_framelets - line0 // h - lines // h if model.framelet_order_reversed
               else line0 // h)
    out = PushFrameSensor(
        framelet_height=model.framelet_height, exposure_duration=model.exposure_duration,
        interframe_delay=model.interframe_delay,
        starting_time=model.starting_time + skipped * model.interframe_delay,
        framelets_flipped=model.framelets_flipped,
        framelet_order_reversed=model.framelet_order_reversed,
        positions=model.positions, t0_ephem=model.t0_ephem, dt_ephem=model.dt_ephem,
        quaternions=model.quaternions, t0_quat=model.t0_quat, dt_quat=model.dt_quat,
        focal_length=model.focal_length, detector=detector, distortion=model.distortion,
        lines=lines, samples=samples, radii=model.radii, sun_positions=model.sun_positions,
        sun_velocities=model.sun_velocities, velocities=model.velocities, name=model.name,
        center_time=model.center_time)
    out.coverage = model.coverage
    return out


#: the least convergence (degrees) of a synthetic stereo pair: one model given twice (or
#: two of one viewpoint) has none and renders two identical images, no parallax at all.
#: Only that degenerate case is refused: a pair of line-scan windows 93 m apart on a
#: 50 km orbit converges 0.1° and still measures relief on a synthetic scene.
MIN_CONVERGENCE_DEG = 0.01

#: the largest DEM side (cells) of a ``--sensor-model`` scene: 4096² cells keep the
#: terrain, its gradients and the albedo (about 60 bytes a cell) near 1 GB.  Windows
#: that need more at half the finer GSD get coarser cells (logged, ``dem_spacing_m``
#: and ``dem_cell_pixels`` in ``scene.json``).
MAX_DEM_SIZE = 4096


def _inside(start: int, length: int, total: int, step: int) -> int:
    """``start`` moved (by whole ``step``s) so that ``start … start + length`` fits in
    ``0 … total`` (``length ≤ total``)."""
    if start < 0:
        return 0
    if start + length > total:
        return ((total - length) // step) * step
    return start


def real_pair(paths, params) -> tuple[Any, dict[str, Any], Any, dict[str, Any]]:
    """Read two models, place the scene under their common footprint and cut windows.

    Returns
    -------
    placement, sensors ({view_00: window, view_01: window}), params (the scene
    parameters with the DEM spacing, size and GSD chosen here), description (for
    ``scene.json``: the files, window origins and GSDs).

    Raises
    ------
    InputError
        A model that is not a frame or line-scan camera on a body, two bodies, no
        common footprint, a window that leaves the image.
    """
    from demtool.camera.info import pair_geometry
    from demtool.maps import body_from_radii
    from demtool.sensors import read_sensor
    from demtool.synth.body import placement, unit_vector

    models = []
    for path in paths:
        model = read_sensor(path)
        if (model.kind not in ("frame", "linescan", "pushframe")
                or type(model) not in (FrameSensor, LineScanSensor, PushFrameSensor)
                or model.radii is None):
            raise InputError(f"{path}: --sensor-model takes frame, line-scan or push-frame "
                             f"models on a "
                             f"body, not a {model.kind or type(model).__name__} model")
        models.append(model)
    (a0, b0), (a1, b1) = models[0].radii, models[1].radii
    if not (math.isclose(a0, a1, rel_tol=1e-6) and math.isclose(b0, b1, rel_tol=1e-6)):
        raise InputError(f"{paths[1]}: the model is on another body than {paths[0]}")
    body = body_from_radii(a0, a0, b0, name=getattr(models[0], "body_name", None),
                           naif_id=getattr(models[0], "body_naif_id", None))
    pair = pair_geometry(models[0], models[1], body)
    if pair.get("overlap_center_lon_deg") is None:
        raise InputError(f"{paths[0]}, {paths[1]}: the two footprints do not overlap")
    if not pair.get("convergence_deg", 0.0) >= MIN_CONVERGENCE_DEG:
        raise InputError(f"{paths[1]}: sees the overlap from where {paths[0]} does "
                         f"(convergence {pair.get('convergence_deg', 0.0):.3g}°, base "
                         f"{pair.get('base_m', 0.0):.4g} m; a stereo pair needs at least "
                         f"{MIN_CONVERGENCE_DEG:g}°): give two views of the area")
    lon, lat = pair["overlap_center_lon_deg"], pair["overlap_center_lat_deg"]
    place = placement(body, lon, lat)
    centre = body.radius * unit_vector(lon, lat)
    size, lines = int(params.image_size), int(params.lines)
    sensors, description, gsds = {}, {}, []
    for index, (path, model) in enumerate(zip(paths, models, strict=True)):
        line, sample = (float(v) for v in model.ground_to_image(centre))
        if not (np.isfinite(line) and np.isfinite(sample)):
            raise InputError(f"{path}: the scene centre ({lon:.5f}°E, {lat:.5f}°) does not "
                             "project into the image")
        line0 = int(round(line - 0.5 * lines))
        size_lines = lines
        if model.kind == "pushframe":  # whole framelets
            h = model.summed_height
            line0 = int(round((line - 0.5 * lines) / h)) * h
            size_lines = max(h, int(round(lines / h)) * h)
        sample0 = int(round(sample - 0.5 * size))
        if size_lines > model.lines or size > model.samples:
            what = f"{size} px" if size_lines == size else f"{size_lines} x {size} px"
            raise InputError(f"{path}: a {what} window centred on the scene centre (line "
                             f"{line:.0f}, sample {sample:.0f}) leaves the {model.lines} x "
                             f"{model.samples} px image; give a smaller --image-size"
                             f"{' or --image-lines' if size_lines != size else ''}")
        # a window that would leave the image is moved inside it (a full-width window
        # of a line scanner, the scene centre a pixel off the image's middle column)
        step = model.summed_height if model.kind == "pushframe" else 1
        line0 = _inside(line0, size_lines, model.lines, step)
        sample0 = _inside(sample0, size, model.samples, 1)
        name = f"view_{index:02d}"
        try:
            cut = window(model, line0, sample0, size_lines, size)
        except ValueError as exc:
            raise InputError(f"{path}: {exc}") from None
        cut.name = name
        sensors[name] = cut
        gsd = _gsd(cut, body)
        gsds.append(gsd)
        description[name] = {"model": str(Path(path)), "window_line0": line0,
                             "window_sample0": sample0, "gsd_m": gsd}
    spacing = 0.5 * min(gsds)
    reach = max(_reach(s, place) for s in sensors.values())
    from demtool.synth.scene import FOOTPRINT_MARGIN

    # 15 % beyond the windows' reach on the sphere: oblique views see further over relief
    side_m = 2.3 * reach / (1.0 - 2.0 * FOOTPRINT_MARGIN)
    if int(math.ceil(side_m / spacing)) + 8 > MAX_DEM_SIZE:
        # large windows: coarser cells keep the DEM (and the renderer's memory) bounded
        spacing = side_m / (MAX_DEM_SIZE - 8)
    dem_size = int(math.ceil(side_m / spacing)) + 8
    params = dataclasses.replace(params, spacing_m=spacing, dem_size=dem_size,
                                 gsd_m=max(gsds),
                                 sensor="frame" if models[0].kind == "frame" else "linescan",
                                 center_lon_deg=lon, center_lat_deg=lat)
    description.update(center_lon_deg=lon, center_lat_deg=lat, dem_spacing_m=spacing,
                       dem_size=dem_size, convergence_deg=pair.get("convergence_deg"),
                       dem_cell_pixels=spacing / min(gsds))
    return place, sensors, params, description


def _gsd(model, body) -> float:
    """Ground distance of one pixel at the window centre (mean of line and sample), m."""
    lc, sc = 0.5 * model.lines, 0.5 * model.samples
    a, b = model.radii
    points = model.image_to_ground(np.array([lc, lc + 1.0, lc]), np.array([sc, sc, sc + 1.0]))
    return float(0.5 * (np.linalg.norm(points[1] - points[0])
                        + np.linalg.norm(points[2] - points[0])))


def _reach(model, place) -> float:
    """Largest |east|, |north| (m, local frame) of the window's border on the sphere."""
    from demtool.camera.info import image_boundary

    line, sample = image_boundary(model.lines, model.samples, 8)
    ray = model.image_to_ray(line, sample)
    from demtool.sensors import ray_ellipsoid_intersection

    xyz = ray_ellipsoid_intersection(ray.origin, ray.direction, place.radius, place.radius)
    local = place.to_local(xyz)
    return float(np.max(np.abs(local[:, :2])))
