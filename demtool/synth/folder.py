"""The one reader of synthetic scene folders and their ``scene.json`` (runner tier).

``scene.json`` (written by ``demtool synth``) describes a scene: target and partner
names, distance, GSD, sun vector, parameters and views.  Stages that take
``--scene`` read it with :func:`read_scene_description`; benchmarks and notebooks read
a whole folder back with :func:`load_scene`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from demtool.synth import Scene


def read_scene_description(path: str | os.PathLike) -> dict[str, Any]:
    """The content of a ``scene.json``; InputError naming the file if it is no JSON object."""
    from demtool import io
    from demtool.errors import InputError

    content = io.read_json(path, "scene file")
    if not isinstance(content, dict):
        raise InputError(f"{path}: scene file is not a JSON object")
    return content


def scene_number(description: dict[str, Any], path: str | os.PathLike | None,
                 key: str) -> float | None:
    """A positive number of a scene description (``gsd_m``), None when the key is absent.

    Raises
    ------
    InputError
        The value is not a positive number (naming the file and the key).
    """
    from demtool.errors import InputError

    if key not in description:
        return None
    value = description[key]
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not number > 0:
        raise InputError(f"{path}: '{key}' must be a positive number, got {value!r}")
    return number


def scene_sun_vector(description: dict[str, Any]) -> np.ndarray | None:
    """The world-frame unit vector toward the sun of a scene description, or None."""
    import numpy as np

    if description.get("sun_vector") is None:
        return None
    return np.asarray(description["sun_vector"], np.float64).reshape(3)


def load_scene(folder: str | os.PathLike, *, with_geometry: bool = True) -> Scene:
    """Read a scene folder written by ``demtool synth`` back into a Scene.

    A ``pinhole`` scene's cameras come from ``cameras.npz``; a ``frame`` scene has
    both ``cameras.npz`` and one ISD per view; a ``linescan`` scene only the ISDs
    (``scene.json``'s ``sensor_models``), read with :func:`demtool.sensors.read_sensor`
    into ``Scene.sensors``, with ``Scene.placement`` rebuilt from the parameters.

    Parameters
    ----------
    folder : path-like
        The ``--out`` folder of ``demtool synth``.
    with_geometry : bool
        If True (default), recompute each view's hit depths and shadow masks by ray
        casting the truth DEM through the view's camera or sensor model (about a second
        per 512 × 512 view); otherwise ``depths`` and ``shadows`` are empty.

    Raises
    ------
    InputError
        A missing or malformed file, naming it.
    """
    import numpy as np

    from demtool import io
    from demtool.errors import InputError
    from demtool.imaging.reflectance import sun_vector as sun_from_angles
    from demtool.sensors.pinhole import cameras_from_arrays
    from demtool.synth import Scene, SceneParams, render

    root = Path(folder)
    description = read_scene_description(root / "scene.json")
    try:
        params = SceneParams(**description["parameters"])
        target, partner = description["target"], description["partner"]
    except (KeyError, TypeError) as exc:
        raise InputError(f"{root / 'scene.json'}: not a demtool synth scene ({exc})") from None
    kind = description.get("sensor", "pinhole")
    cameras = ({} if kind == "linescan"
               else cameras_from_arrays(io.read_npz(root / "cameras.npz", "cameras")))
    placement, sensors = _scene_sensors(root, description, params, kind)
    names = tuple(description.get("names", sorted(cameras or sensors)))
    dem = io.read_raster(root / "truth_dem.tif", what="truth DEM")
    albedo = io.read_raster(root / "albedo.tif", what="albedo map")
    truth_target = io.read_raster(root / "truth_dem_target.tif", what="target truth DEM")
    images = {n: io.read_image(root / f"{n}.tif", what=f"image {n}").data for n in names}
    depths: dict[str, np.ndarray] = {}
    shadows: dict[str, np.ndarray] = {}
    sun = sun_from_angles(params.sun_incidence_deg, params.sun_azimuth_deg)
    if with_geometry:
        field = render.height_field(dem.data.astype(np.float64), dem.transform)
        views = sensors or cameras
        for name in names:
            geometry = render.view_geometry(field, albedo.data.astype(np.float64),
                                            views[name], sun, placement=placement)
            depths[name], shadows[name] = geometry.depth, geometry.shadow
    return Scene(params=params, dem=dem.data, dem_transform=dem.transform, albedo=albedo.data,
                 names=names, target=target, partner=partner, cameras=cameras, images=images,
                 depths=depths, shadows=shadows, truth_target=truth_target.data,
                 sun_vector=sun, gsd_m=float(description["gsd_m"]),
                 distance_m=float(description["distance_m"]),
                 dn_per_reflectance=float(description.get("dn_per_reflectance", np.nan)),
                 render_time_s=float(description.get("render_time_s", np.nan)),
                 timings=dict(description.get("timings_s", {})), sensor=kind,
                 placement=placement, sensors=sensors)


def _scene_sensors(root: Path, description: dict[str, Any], params: Any, kind: str
                   ) -> tuple[Any, dict[str, Any]]:
    """The placement and the sensor models of a ``frame`` or ``linescan`` scene folder
    (``(None, {})`` for a ``pinhole`` one).

    Raises
    ------
    InputError
        ``scene.json`` names no ISDs for a sensor scene, or an ISD is missing or bad
        (naming the file).
    """
    from demtool.errors import InputError
    from demtool.sensors import read_sensor
    from demtool.synth.body import placement

    if kind == "pinhole":
        return None, {}
    files = description.get("sensor_models")
    if not isinstance(files, dict) or not files:
        raise InputError(f"{root / 'scene.json'}: a '{kind}' scene without 'sensor_models' "
                         "(the ISD of each view); write it again with demtool synth")
    try:
        place = placement(params.body, params.center_lon_deg, params.center_lat_deg)
    except ValueError as exc:
        raise InputError(f"{root / 'scene.json'}: {exc}") from None
    return place, {name: read_sensor(root / str(file)) for name, file in files.items()}
