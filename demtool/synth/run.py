"""Runner of ``demtool synth``: parameters → :func:`demtool.synth.make_scene` → files.

:func:`run_synth` renders a scene and writes its folder (see CONTRIBUTING.md,
"Synthetic scene folder") in one transaction with :func:`write_scene`.  The scene is
read back by :func:`demtool.synth.folder.load_scene`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.stagerun import StageRun

if TYPE_CHECKING:
    from demtool.provenance import Provenance
    from demtool.synth import Scene, SceneParams


def write_scene(scene: Scene, out: str | os.PathLike, prov: Provenance) -> list[Path]:
    """Write every file of a scene folder (see CONTRIBUTING.md), in one transaction.

    Returns the written paths (the sidecar ``scene.json.json`` last).
    """
    import numpy as np

    from demtool import io
    from demtool.sensors.isd import write_isd
    from demtool.sensors.pinhole import cameras_to_arrays
    from demtool.synth import render
    from demtool.synth.maptruth import truth_map
    from demtool.synth.views import (
        sensor_view_summaries,
        to_grid_frame,
        view_angles,
        view_summaries,
    )

    folder = Path(out)
    params = scene.params.as_dict()
    sun = scene.sun_vector
    written: list[Path] = []
    with io.output_transaction():
        for name in scene.names:
            tags = {"frame": f"image:{name}", "view_name": name, "scene_target": scene.target,
                    "scene_partner": scene.partner, "sun_vector": sun.tolist()}
            if name in scene.cameras:
                camera = scene.cameras[name]
                view_vector = camera.center / np.linalg.norm(camera.center)
                tags.update(sun_vector_grid=to_grid_frame(camera, sun),
                            view_vector_grid=to_grid_frame(camera, view_vector),
                            up_vector_grid=to_grid_frame(camera, [0.0, 0.0, 1.0]),
                            camera=camera.as_dict())
            if name in scene.sensors:
                tags.update(sensor_model=f"{name}.json", sensor_kind=scene.sensor)
            tags.update(units="DN", bit_depth=scene.params.bit_depth)
            if name in scene.cameras:
                tags.update(view_angles(scene.cameras[name], sun))
            written.append(io.write_raster(folder / f"{name}.tif", scene.images[name],
                                           transform=io.image_frame_transform(1.0),
                                           tags=prov.tags(**tags)))
            if name in scene.sensors:
                written.append(write_isd(folder / f"{name}.json", scene.sensors[name]))
        written.append(io.write_raster(
            folder / "truth_dem.tif", scene.dem, transform=scene.dem_transform,
            tags=prov.tags(frame="map:local", units="m",
                           content="truth heights above the mean surface")))
        written.append(io.write_raster(
            folder / "albedo.tif", scene.albedo, transform=scene.dem_transform,
            tags=prov.tags(frame="map:local", units="1", content="normal albedo")))
        written.append(io.write_raster(
            folder / "truth_dem_target.tif", scene.truth_target,
            transform=io.image_frame_transform(scene.gsd_m),
            tags=prov.tags(frame=f"image:{scene.target}", units="m",
                           content="truth heights above the mean surface, target pixels")))
        if scene.cameras:
            arrays = cameras_to_arrays(scene.names, [scene.cameras[n] for n in scene.names])
            arrays.update(target=np.asarray(scene.target), partner=np.asarray(scene.partner))
            written.append(io.write_npz(folder / "cameras.npz", "cameras", arrays))
        description = {
            "target": scene.target, "partner": scene.partner, "names": list(scene.names),
            "distance_m": scene.distance_m, "gsd_m": scene.gsd_m,
            "sun_vector": sun.tolist(), "seed": scene.params.seed,
            "frame": "world: X east, Y north, Z up, metres, origin at the scene centre, "
                     "Z = 0 the mean surface",
            "dem_transform": list(scene.dem_transform)[:6],
            "dn_per_reflectance": scene.dn_per_reflectance,
            "reflectance_model": "lunar-lambert",
            "parameters": params,
            "views": view_summaries(scene) if scene.cameras else sensor_view_summaries(scene),
            "render_time_s": round(scene.render_time_s, 3),
            "timings_s": {k: round(v, 3) for k, v in scene.timings.items()},
        }
        if scene.sensors:
            truth = truth_map(render.height_field(scene.dem.astype(np.float64),
                                                  scene.dem_transform),
                              scene.placement, [scene.sensors[scene.target],
                                                scene.sensors[scene.partner]], scene.gsd_m)
            written.append(io.write_raster(
                folder / "truth_dem_map.tif", truth.heights, transform=truth.grid.transform,
                crs=truth.grid.crs,
                tags=prov.tags(units="m", **scene.placement.body.tags(),
                               content="truth heights above the reference sphere over the "
                                       f"common footprint of {scene.target} and "
                                       f"{scene.partner}")))
            description.update(
                sensor=scene.sensor, body=scene.placement.tags(),
                sensor_models={n: f"{n}.json" for n in scene.names},
                sun_position_body_m=scene.placement.sun_position(sun).tolist(),
                truth_dem_map={"file": "truth_dem_map.tif", "crs": truth.grid.crs.to_wkt(),
                               "shape": list(truth.grid.shape), "gsd_m": scene.gsd_m})
        else:
            description["sensor"] = "pinhole"
        written.append(io.write_json(folder / "scene.json", description))
        summary = {"views": len(scene.names), "image_size": scene.params.image_size,
                   "dem_size": scene.params.dem_size,
                   "height_range_m": [float(scene.dem.min()), float(scene.dem.max())],
                   "render_time_s": round(scene.render_time_s, 3)}
        written.append(prov.write_sidecar(folder / "scene.json", summary,
                                          outputs=list(written)))
    return written


def run_synth(out: str | os.PathLike, params: SceneParams | None = None, *,
              resolved: dict[str, Any] | None = None, sensor_models=None) -> Scene:
    """Render the scene of ``params`` and write it into ``out``.

    Parameters
    ----------
    out : path-like
        Output folder (created if needed).
    params : SceneParams, optional
        The scene's parameters (default: the demo scene).
    resolved : dict, optional
        The command's resolved options, for the provenance record (defaults to
        ``params.as_dict()``).
    sensor_models : (path, path), optional
        Render through windows of these two real models (``--sensor-model``,
        :func:`demtool.synth.real.real_pair`; it chooses the DEM spacing, size and GSD).

    Raises
    ------
    ParameterError
        Parameters that cannot make a scene, naming the option.
    """
    from demtool.synth import SceneParams, make_scene

    params = params or SceneParams()
    real = None
    if sensor_models is not None:
        from demtool.synth.real import real_pair

        place, sensors, params, windows = real_pair(sensor_models, params)
        real = (place, sensors)
    run = StageRun("synth", params, resolved=resolved, folders={"--out": out})
    if real is not None:
        run.log.info("scene at %.5f°E %.5f° under the pair's common footprint; DEM %d × %d "
                     "at %.3g m (cells of %.2f pixels of the finer GSD); windows %s",
                     windows["center_lon_deg"],
                     windows["center_lat_deg"], params.dem_size, params.dem_size,
                     params.spacing_m, windows["dem_cell_pixels"], ", ".join(
                         f"{n}: {w['model']} from line {w['window_line0']}, sample "
                         f"{w['window_sample0']} ({w['gsd_m']:.3g} m/px)"
                         for n, w in windows.items() if n.startswith("view_")))
    run.log.info("rendering %d views of %d × %d px over a %d × %d DEM (%.2f m cells), "
                 "seed %d", 2 if real else params.n_views,
                 params.lines if real or params.sensor == "linescan" else params.image_size,
                 params.image_size, params.dem_size, params.dem_size, params.spacing_m,
                 params.seed)
    scene = make_scene(params, sensor_models=real)
    with run.transaction():
        written = write_scene(scene, out, run.provenance)
    run.log.info("scene rendered in %.1f s: heights %.1f … %.1f m, target %s, partner %s "
                 "(%s)", scene.render_time_s, float(scene.dem.min()),
                 float(scene.dem.max()), scene.target, scene.partner,
                 f"convergence {windows['convergence_deg']:.1f}°" if real
                 else f"B/H {params.partner_bh:.2f}")
    run.log.info("wrote %d files into %s: %s", len(written), out,
                 ", ".join(p.name for p in written))
    return scene
