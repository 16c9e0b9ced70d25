"""`demtool synth`: render a synthetic planetary scene into a folder.

Tiers: :func:`command` (click, options only) → :func:`run_synth` (the runner:
parameters → :func:`demtool.synth.make_scene` → :func:`write_scene`) →
:mod:`demtool.synth` (the pure core).  :func:`load_scene` reads a scene folder back
into a :class:`demtool.synth.Scene` for benchmarks and notebooks.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from demtool import option_types as ot
from demtool.cli import STAGES
from demtool.options import out_dir, seed

if TYPE_CHECKING:
    import numpy as np

    from demtool.provenance import Provenance
    from demtool.synth import Scene, SceneParams

# command-line option name -> SceneParams field
OPTION_TO_PARAM = {
    "seed": "seed",
    "size": "dem_size",
    "spacing": "spacing_m",
    "relief": "fractal_rms_m",
    "spectral_exponent": "spectral_exponent",
    "craters": "crater_count",
    "crater_exponent": "crater_exponent",
    "crater_min": "crater_min_diameter_m",
    "crater_max": "crater_max_diameter_m",
    "crater_depth": "crater_depth_ratio",
    "rim_height": "rim_height_ratio",
    "boulders": "boulder_count",
    "boulder_height": "boulder_height_m",
    "albedo": "albedo_mean",
    "albedo_variation": "albedo_variation",
    "views": "n_views",
    "image_size": "image_size",
    "altitude": "altitude_m",
    "gsd": "gsd_m",
    "partner_bh": "partner_bh",
    "bh_min": "bh_min",
    "bh_max": "bh_max",
    "sun_incidence": "sun_incidence_deg",
    "sun_azimuth": "sun_azimuth_deg",
    "exposure": "exposure_dn",
    "gain": "gain_e_per_dn",
    "read_noise": "read_noise_dn",
    "noise": "noise",
}


# --------------------------------------------------------------------------------------
# Geometry tags
# --------------------------------------------------------------------------------------


def to_grid_frame(camera, vector) -> list[float]:
    """A world vector in a view's grid frame (x image right, y image up, z toward camera)."""
    import numpy as np

    c = camera.R @ np.asarray(vector, dtype=np.float64)
    return [float(c[0]) + 0.0, float(-c[1]) + 0.0, float(-c[2]) + 0.0]  # no -0.0


def view_angles(camera, sun) -> dict[str, float]:
    """Incidence, emission and phase angles (degrees) at the scene centre (flat surface)."""
    import numpy as np

    view = camera.center / np.linalg.norm(camera.center)
    return {"incidence_deg": float(np.degrees(np.arccos(np.clip(sun[2], -1, 1)))),
            "emission_deg": float(np.degrees(np.arccos(np.clip(view[2], -1, 1)))),
            "phase_deg": float(np.degrees(np.arccos(np.clip(view @ sun, -1, 1))))}


def view_summaries(scene: Scene) -> list[dict[str, Any]]:
    """Per-view geometry for ``scene.json``: B/H and convergence to the target, angles."""
    import numpy as np

    target = scene.cameras[scene.target]
    views = []
    for name in scene.names:
        camera = scene.cameras[name]
        baseline = float(np.linalg.norm(camera.center - target.center))
        convergence = float(np.degrees(np.arccos(np.clip(camera.axis @ target.axis, -1, 1))))
        views.append({
            "name": name, "file": f"{name}.tif",
            "role": "target" if name == scene.target else
                    "partner" if name == scene.partner else "other",
            "center_m": camera.center.tolist(),
            "baseline_m": baseline,
            "bh_to_target": baseline / scene.distance_m,
            "convergence_deg": convergence,
            "gsd_m_at_centre": float(np.linalg.norm(camera.center) / camera.focal_px),
            **view_angles(camera, scene.sun_vector),
            "shadow_fraction": float(np.mean(scene.shadows[name])) if scene.shadows else None,
        })
    return views


# --------------------------------------------------------------------------------------
# Runner
# --------------------------------------------------------------------------------------


def write_scene(scene: Scene, out: str | os.PathLike, prov: Provenance) -> list[Path]:
    """Write every file of a scene folder (see CONTRIBUTING.md), in one transaction.

    Returns the written paths (the sidecar ``scene.json.json`` last).
    """
    import numpy as np

    from demtool import io
    from demtool.camera import cameras_to_arrays

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


def run_synth(out: str | os.PathLike, params: SceneParams,
              resolved: dict[str, Any] | None = None) -> Scene:
    """Render the scene of ``params`` and write it into ``out``.

    Parameters
    ----------
    out : path-like
        Output folder (created if needed).
    params : SceneParams
        The scene's parameters (checked by :func:`demtool.synth.make_scene`).
    resolved : dict, optional
        The command's resolved options, for the provenance record (defaults to
        ``params.as_dict()``).
    """
    from demtool.errors import ParameterError
    from demtool.logs import get_logger
    from demtool.provenance import Provenance
    from demtool.synth import check_parameters, make_scene

    log = get_logger("synth")
    prov = Provenance("synth", resolved or params.as_dict(), inputs=[])
    try:
        check_parameters(params)
    except ParameterError as exc:
        raise ParameterError(option_names(str(exc))) from None
    log.info("rendering %d views of %d × %d px over a %d × %d DEM (%.2f m cells), seed %d",
             params.n_views, params.image_size, params.image_size, params.dem_size,
             params.dem_size, params.spacing_m, params.seed)
    try:
        scene = make_scene(params)
    except ParameterError as exc:
        raise ParameterError(option_names(str(exc))) from None
    written = write_scene(scene, out, prov)
    log.info("scene rendered in %.1f s: heights %.1f … %.1f m, target %s, partner %s "
             "(B/H %.2f)", scene.render_time_s, float(scene.dem.min()), float(scene.dem.max()),
             scene.target, scene.partner, params.partner_bh)
    log.info("wrote %d files into %s: %s", len(written), out,
             ", ".join(p.name for p in written))
    return scene


def load_scene(folder: str | os.PathLike, *, with_geometry: bool = True) -> Scene:
    """Read a scene folder written by ``demtool synth`` back into a Scene.

    Parameters
    ----------
    folder : path-like
        The ``--out`` folder of ``demtool synth``.
    with_geometry : bool
        If True (default), recompute each view's hit depths and shadow masks by ray
        casting the truth DEM (about a second per 512 × 512 view); otherwise
        ``depths`` and ``shadows`` are empty.

    Raises
    ------
    InputError
        A missing or malformed file, naming it.
    """
    import numpy as np

    from demtool import io
    from demtool.camera import cameras_from_arrays
    from demtool.errors import InputError
    from demtool.reflectance import sun_vector as sun_from_angles
    from demtool.synth import Scene, SceneParams, render

    root = Path(folder)
    description = io.read_json(root / "scene.json", "scene description")
    try:
        params = SceneParams(**description["parameters"])
        target, partner = description["target"], description["partner"]
    except (KeyError, TypeError) as exc:
        raise InputError(f"{root / 'scene.json'}: not a demtool synth scene ({exc})") from None
    cameras = cameras_from_arrays(io.read_npz(root / "cameras.npz", "cameras"))
    names = tuple(description.get("names", sorted(cameras)))
    dem = io.read_raster(root / "truth_dem.tif", what="truth DEM")
    albedo = io.read_raster(root / "albedo.tif", what="albedo map")
    truth_target = io.read_raster(root / "truth_dem_target.tif", what="target truth DEM")
    images = {n: io.read_image(root / f"{n}.tif", what=f"image {n}").data for n in names}
    depths: dict[str, np.ndarray] = {}
    shadows: dict[str, np.ndarray] = {}
    sun = sun_from_angles(params.sun_incidence_deg, params.sun_azimuth_deg)
    if with_geometry:
        field = render.height_field(dem.data.astype(np.float64), dem.transform)
        for name in names:
            geometry = render.view_geometry(field, albedo.data.astype(np.float64),
                                            cameras[name], sun)
            depths[name], shadows[name] = geometry.depth, geometry.shadow
    return Scene(params=params, dem=dem.data, dem_transform=dem.transform, albedo=albedo.data,
                 names=names, target=target, partner=partner, cameras=cameras, images=images,
                 depths=depths, shadows=shadows, truth_target=truth_target.data,
                 sun_vector=sun, gsd_m=float(description["gsd_m"]),
                 distance_m=float(description["distance_m"]),
                 dn_per_reflectance=float(description.get("dn_per_reflectance", np.nan)),
                 render_time_s=float(description.get("render_time_s", np.nan)),
                 timings=dict(description.get("timings_s", {})))


def option_names(message: str) -> str:
    """A core message with SceneParams field names replaced by the command's options."""
    import re

    for option, name in OPTION_TO_PARAM.items():
        message = re.sub(rf"\b{name}\b", "--" + option.replace("_", "-"), message)
    return message


def params_from_options(options: dict[str, Any]) -> SceneParams:
    """SceneParams from the command's options (unset options keep their defaults)."""
    from demtool.synth import SceneParams

    values = {OPTION_TO_PARAM[k]: v for k, v in options.items()
              if k in OPTION_TO_PARAM and v is not None}
    if options.get("no_craters"):
        values["crater_count"] = 0
    return SceneParams(**values)


# --------------------------------------------------------------------------------------
# Command
# --------------------------------------------------------------------------------------

_POSITIVE = ot.FloatRange(min=0.0, min_open=True)
_NON_NEGATIVE = ot.FloatRange(min=0.0)


def _default(name: str) -> Any:
    from demtool.synth.params import SceneParams

    return getattr(SceneParams(), OPTION_TO_PARAM[name])


def _option(flag: str, kind: Any, help_text: str, **kwargs: Any):
    """A scene option whose default is the SceneParams default (shown in --help)."""
    name = flag.lstrip("-").split("/")[0].replace("-", "_")
    return click.option(flag, type=kind, default=_default(name), show_default=True,
                        help=help_text, **kwargs)


@click.command(name="synth", help=STAGES["synth"] + """

Writes into DIR: view_00.tif (the nadir target), view_01.tif (its stereo partner),
view_02.tif …, truth_dem.tif (map grid), truth_dem_target.tif (target pixel grid),
albedo.tif, cameras.npz, scene.json and the provenance record scene.json.json.
Defaults give the demo scene (512 × 512 DEM at 1 m, 8 views of 512 × 512 px).""")
@out_dir("Output folder for the scene (created if needed).")
@seed()
@_option("--size", ot.IntRange(min=16), "DEM size in cells (square).")
@_option("--spacing", _POSITIVE, "DEM cell size, metres.")
@_option("--relief", _NON_NEGATIVE, "RMS height of the fractal relief, metres.")
@_option("--spectral-exponent", ot.FloatRange(min=1.0, max=5.0),
         "Exponent β of the relief's power spectrum P(k) ∝ k^-β (β = 2H + 2).")
@_option("--craters", ot.IntRange(min=0), "Number of craters (0 = none).")
@click.option("--no-craters", is_flag=True, default=False, help="Same as --craters 0.")
@_option("--crater-exponent", _POSITIVE,
         "Slope b of the cumulative size-frequency law N(>D) ∝ D^-b.")
@_option("--crater-min", _POSITIVE, "Smallest crater diameter, metres.")
@_option("--crater-max", _POSITIVE, "Largest crater diameter, metres.")
@_option("--crater-depth", ot.FloatRange(min=0.0, max=1.0),
         "Crater depth (rim crest to floor) / diameter (Pike 1977).")
@_option("--rim-height", ot.FloatRange(min=0.0, max=1.0),
         "Crater rim height above the surroundings / diameter (Pike 1977).")
@_option("--boulders", ot.IntRange(min=0), "Number of boulders (0 = none).")
@_option("--boulder-height", _NON_NEGATIVE, "Mean boulder height, metres.")
@_option("--albedo", ot.FloatRange(min=0.0, max=1.0, min_open=True), "Mean normal albedo.")
@_option("--albedo-variation", ot.FloatRange(min=0.0, max=1.0, max_open=True),
         "Relative albedo variation (±, low frequency).")
@_option("--views", ot.IntRange(min=2, max=99), "Number of views (target, partner, others).")
@_option("--image-size", ot.IntRange(min=16), "Image width and height, pixels.")
@_option("--altitude", _POSITIVE, "Camera height above the mean surface, metres.")
@_option("--gsd", _POSITIVE, "Target ground sampling distance, metres/pixel.")
@_option("--partner-bh", ot.FloatRange(min=0.0, max=2.0, min_open=True),
         "Base-to-height ratio of the stereo partner (baseline along image x).")
@_option("--bh-min", _NON_NEGATIVE, "Smallest B/H (to the target) of the other views.")
@_option("--bh-max", _NON_NEGATIVE, "Largest B/H (to the target) of the other views.")
@_option("--sun-incidence", ot.FloatRange(min=0.0, max=90.0, max_open=True),
         "Sun incidence angle from the zenith, degrees.")
@_option("--sun-azimuth", ot.FLOAT, "Sun azimuth, degrees clockwise from north.")
@_option("--exposure", _POSITIVE, "Expected DN of a flat mean-albedo surface seen at nadir.")
@_option("--gain", _POSITIVE, "Photon gain, electrons per DN.")
@_option("--read-noise", _NON_NEGATIVE, "Read noise, DN (standard deviation).")
@_option("--noise/--no-noise", bool, "Add photon (Poisson) and read (Gaussian) noise.")
@click.pass_context
def command(ctx: click.Context, out: str, **options: Any) -> None:
    """Thin wrapper: options → SceneParams → :func:`run_synth`."""
    from click.core import ParameterSource

    from demtool.options import resolved_params

    if options["no_craters"] and ctx.get_parameter_source("craters") in (
            ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT) and options["craters"]:
        raise click.BadParameter("give either --craters N or --no-craters, not both",
                                 param_hint="'--no-craters'")
    params = params_from_options(options)
    run_synth(out, params, resolved=resolved_params(ctx))
