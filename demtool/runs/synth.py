"""Runner of ``demtool synth``: parameters → :func:`demtool.synth.make_scene` → files.

:func:`run_synth` renders a scene and writes its folder (see CONTRIBUTING.md,
"Synthetic scene folder") in one transaction with :func:`write_scene`.  The scene is
read back by :func:`demtool.runs.scene.load_scene`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from demtool.runs import StageRun

if TYPE_CHECKING:
    from demtool.provenance import Provenance
    from demtool.synth import Scene, SceneParams


def write_scene(scene: Scene, out: str | os.PathLike, prov: Provenance) -> list[Path]:
    """Write every file of a scene folder (see CONTRIBUTING.md), in one transaction.

    Returns the written paths (the sidecar ``scene.json.json`` last).
    """
    import numpy as np

    from demtool import io
    from demtool.camera import cameras_to_arrays
    from demtool.synth.views import to_grid_frame, view_angles, view_summaries

    folder = Path(out)
    params = scene.params.as_dict()
    sun = scene.sun_vector
    written: list[Path] = []
    with io.output_transaction():
        for name in scene.names:
            camera = scene.cameras[name]
            view_vector = camera.center / np.linalg.norm(camera.center)
            tags = prov.tags(
                frame=f"image:{name}", view_name=name, scene_target=scene.target,
                scene_partner=scene.partner, sun_vector=sun.tolist(),
                sun_vector_grid=to_grid_frame(camera, sun),
                view_vector_grid=to_grid_frame(camera, view_vector),
                up_vector_grid=to_grid_frame(camera, [0.0, 0.0, 1.0]),
                camera=camera.as_dict(), units="DN", bit_depth=scene.params.bit_depth,
                **view_angles(camera, sun))
            written.append(io.write_raster(folder / f"{name}.tif", scene.images[name],
                                           transform=io.image_frame_transform(1.0), tags=tags))
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
            "parameters": params, "views": view_summaries(scene),
            "render_time_s": round(scene.render_time_s, 3),
            "timings_s": {k: round(v, 3) for k, v in scene.timings.items()},
        }
        written.append(io.write_json(folder / "scene.json", description))
        summary = {"views": len(scene.names), "image_size": scene.params.image_size,
                   "dem_size": scene.params.dem_size,
                   "height_range_m": [float(scene.dem.min()), float(scene.dem.max())],
                   "render_time_s": round(scene.render_time_s, 3)}
        written.append(prov.write_sidecar(folder / "scene.json", summary,
                                          outputs=list(written)))
    return written


def run_synth(out: str | os.PathLike, params: SceneParams | None = None, *,
              resolved: dict[str, Any] | None = None) -> Scene:
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

    Raises
    ------
    ParameterError
        Parameters that cannot make a scene, naming the option.
    """
    from demtool.synth import SceneParams, make_scene

    params = params or SceneParams()
    run = StageRun("synth", params, resolved=resolved, folders={"--out": out})
    run.log.info("rendering %d views of %d × %d px over a %d × %d DEM (%.2f m cells), "
                 "seed %d", params.n_views, params.image_size, params.image_size,
                 params.dem_size, params.dem_size, params.spacing_m, params.seed)
    scene = make_scene(params)
    with run.transaction():
        written = write_scene(scene, out, run.provenance)
    run.log.info("scene rendered in %.1f s: heights %.1f … %.1f m, target %s, partner %s "
                 "(B/H %.2f)", scene.render_time_s, float(scene.dem.min()),
                 float(scene.dem.max()), scene.target, scene.partner, params.partner_bh)
    run.log.info("wrote %d files into %s: %s", len(written), out,
                 ", ".join(p.name for p in written))
    return scene
