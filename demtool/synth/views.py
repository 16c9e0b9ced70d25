"""View geometry of a synthetic scene: grid-frame vectors and per-view angles.

Pure functions (arrays in, numbers out) used to tag the rendered images and to
describe the views in ``scene.json``.  Frames: see CONTRIBUTING.md ("Grid frame of an
image-frame raster").
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from demtool.synth.scene import Scene


def to_grid_frame(camera, vector) -> list[float]:
    """A world vector in a view's grid frame (x image right, y image up, z toward camera)."""
    c = camera.R @ np.asarray(vector, dtype=np.float64)
    return [float(c[0]) + 0.0, float(-c[1]) + 0.0, float(-c[2]) + 0.0]  # no -0.0


def view_angles(camera, sun) -> dict[str, float]:
    """Incidence, emission and phase angles (degrees) at the scene centre (flat surface)."""
    view = camera.center / np.linalg.norm(camera.center)
    return {"incidence_deg": float(np.degrees(np.arccos(np.clip(sun[2], -1, 1)))),
            "emission_deg": float(np.degrees(np.arccos(np.clip(view[2], -1, 1)))),
            "phase_deg": float(np.degrees(np.arccos(np.clip(view @ sun, -1, 1))))}


def view_summaries(scene: Scene) -> list[dict[str, Any]]:
    """Per-view geometry for ``scene.json``: B/H and convergence to the target, angles."""
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


def sensor_view_summaries(scene: Scene) -> list[dict[str, Any]]:
    """Per-view geometry of a scene rendered through body-fixed sensor models, at each
    view's image centre: sensor kind, ISD file, spacecraft centre (local and body-fixed
    metres), range, emission and convergence to the target (degrees)."""
    place = scene.placement
    ground = place.origin
    target = scene.sensors[scene.target]
    views = []
    for name in scene.names:
        model = scene.sensors[name]
        centre_line = 0.5 * model.lines
        position = model.camera_center(centre_line)
        line, _ = model.ground_to_image(ground)
        seen_from = model.camera_center(line) - ground
        target_line, _ = target.ground_to_image(ground)
        to_target = target.camera_center(target_line) - ground
        cos_conv = seen_from @ to_target / (np.linalg.norm(seen_from) * np.linalg.norm(to_target))
        up = place.frame[2]
        views.append({
            "name": name, "file": f"{name}.tif", "isd": f"{name}.json", "kind": model.kind,
            "role": "target" if name == scene.target else
                    "partner" if name == scene.partner else "other",
            "center_body_m": position.tolist(),
            "center_local_m": place.to_local(position).tolist(),
            "range_to_scene_centre_m": float(np.linalg.norm(seen_from)),
            "emission_deg": float(np.degrees(np.arccos(np.clip(
                seen_from @ up / np.linalg.norm(seen_from), -1, 1)))),
            "convergence_deg": float(np.degrees(np.arccos(np.clip(cos_conv, -1, 1)))),
            "shadow_fraction": float(np.mean(scene.shadows[name])) if scene.shadows else None,
        })
    return views
