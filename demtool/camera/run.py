"""Runner of ``demtool camera``: what sensor models see (ISIS ``caminfo``, ASP
``camera_footprint``).

The report goes to stdout, the command's product as with ISIS's ``caminfo``/``campt``:
a table by default, the JSON report with ``as_json``; logs stay on stderr.  ``out``
also writes the JSON report (with its provenance sidecar) in one output transaction.
"""

from __future__ import annotations

import json
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from demtool.stagerun import StageRun, sidecar_path

if TYPE_CHECKING:
    from demtool.camera.params import CameraParams
    from demtool.maps import Body


def _named_body(text: str) -> Body:
    from demtool.errors import ParameterError
    from demtool.maps import body_by_naif_id, body_by_name

    try:
        return body_by_naif_id(int(text)) if text.strip().lstrip("-").isdigit() \
            else body_by_name(text)
    except KeyError as exc:
        raise ParameterError(f"--body: {exc.args[0]}") from None


def _isd_naif_id(path: Path) -> int | None:
    """The target's NAIF id an ALE ISD names in its ``naif_keywords`` (BODY<id>_RADII)."""
    try:
        with open(path, encoding="utf-8") as handle:
            keywords = json.load(handle).get("naif_keywords") or {}
    except (OSError, ValueError, AttributeError):
        return None
    ids = {int(m.group(1)) for k in keywords if (m := re.fullmatch(r"BODY(-?\d+)_RADII", k))}
    return ids.pop() if len(ids) == 1 else None


def _body_of(model, path: Path, named: Body | None) -> Body | None:
    """The body a model is on (None: the local world frame of a pinhole)."""
    from demtool.errors import InputError
    from demtool.maps import body_from_radii
    from demtool.sensors import TsaiCamera

    if model.radii is None:
        if isinstance(model, TsaiCamera):
            raise InputError(f"{path}: a .tsai model does not say which body it sees; give "
                             "--body (e.g. --body Moon)")
        return None
    a, b = model.radii
    if named is not None:
        from demtool.sensors.validate import check_named_body

        check_named_body(model, named, path)
        body = body_from_radii(a, a, b, name=named.name, naif_id=named.naif_id)
    else:
        naif = _isd_naif_id(path) if path.suffix.lower() == ".json" else None
        # a cube names its body (TargetName, BODY<code>_RADII): kept when PROJ lacks it
        body = body_from_radii(a, a, b, naif_id=naif or getattr(model, "body_naif_id", None),
                               name=getattr(model, "body_name", None))
    if getattr(model, "height_reference", "sphere") == "ellipsoid":
        from dataclasses import replace  # an RPC: geodetic heights above its ellipsoid

        body = replace(body, height_reference="ellipsoid")
    _check_outside(model, path, body, named is not None)
    return body


def _check_outside(model, path: Path, body: Body, named: bool) -> None:
    """InputError when the camera centre lies inside the body, deeper than its lowest
    surface (:func:`demtool.sensors.body_view.relief_band`): the model is not in that
    body's body-fixed frame (a local-frame camera given ``--body``)."""
    import numpy as np

    from demtool.errors import InputError

    lines = getattr(model, "lines", 0) or 0
    center = np.asarray(model.camera_center(0.5 * lines), dtype=np.float64).reshape(-1)[:3]
    a, b = model.radii
    if not np.isfinite(center).all():
        return
    from demtool.sensors.body_view import height_above_ellipsoid, relief_band

    # below the body's lowest surface (a rover below the datum is on the surface)
    if height_above_ellipsoid(center, a, b) < relief_band(a, b).low:
        distance = float(np.linalg.norm(center))
        hint = ("a local-frame camera (rover, lander, lab rig): --body only applies to "
                "models in the body's body-fixed frame" if named else
                "the model is not in the body-fixed frame of the body it names")
        raise InputError(f"{path}: the camera centre is {distance:.6g} m from the centre of "
                         f"{body.name} (radius {a:.6g} m), inside the body: {hint}")


def on_tie_point_plane(path: Path, models: dict) -> dict:
    """The cameras of an unaligned ``bundle.npz`` in a frame whose plane Z = 0 is the
    plane of its tie points (up towards the cameras); other files' models as they are.

    An unaligned bundle is in COLMAP's arbitrary frame (scale, rotation, origin), where
    the local frame's ground Z = 0 means nothing and ``pairs`` found no pair (issue 46).
    The tie points are the ground the bundle measured: their least-squares plane (the
    singular vector of least variance) is the surface the footprints are taken to, so
    overlaps, convergence and B/H — all free of the frame's scale — are the block's.
    """
    import dataclasses
    import zipfile

    import numpy as np

    if path.suffix.lower() != ".npz":
        return models
    try:
        with np.load(path, allow_pickle=False) as npz:
            if str(npz["kind"]) != "bundle" or bool(npz["aligned"]):
                return models
            points = np.asarray(npz["points"], dtype=np.float64)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return models
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < 3:
        return models
    centre = points.mean(axis=0)
    _, _, axes = np.linalg.svd(points - centre, full_matrices=False)
    normal = axes[2]
    centres = np.array([-m.R.T @ m.t for m in models.values()])
    if np.mean((centres - centre) @ normal) < 0:
        normal = -normal
    east = axes[0]
    frame = np.array([east, np.cross(normal, east), normal])  # rows: new x, y, z (up)
    return {name: dataclasses.replace(m, R=m.R @ frame.T, t=m.R @ centre + m.t)
            for name, m in models.items()}


def _sized(model):
    """A pinhole without an image size (a ``.tsai`` carries none) gets the size centred on
    its principal point, with a note."""
    import dataclasses

    from demtool.sensors import PinholeCamera

    if not isinstance(model, PinholeCamera) or (model.width > 0 and model.height > 0):
        return model
    width = max(1, round(2 * (model.K[0, 2] + 0.5)))
    height = max(1, round(2 * (model.K[1, 2] + 0.5)))
    sized = dataclasses.replace(model, width=width, height=height)
    object.__setattr__(sized, "notes", [f"the model gives no image size: {height} x {width} "
                                        "px assumed, centred on the principal point"])
    return sized


def read_models(paths: Sequence[str | os.PathLike], body: Body | None = None):
    """Read every model of every file, by unique name, with its body and file.

    Returns
    -------
    models : dict name → SensorModel
    bodies : dict name → Body or None
    files : dict name → str
    """
    from demtool.sensors import read_sensors

    radii = (body.a, body.c) if body is not None else None
    models, bodies, files = {}, {}, {}
    for raw in paths:
        path = Path(raw)
        found = on_tie_point_plane(path, read_sensors(path, radii=radii,
                                                      require_surface=False))
        for name, model in found.items():
            # a file of one model is named by its file, as given (pairs.txt, the tables):
            # an ISD's internal image id need not match a renamed file (issue 46)
            key = path.stem if len(found) == 1 else (name or path.stem)
            if key in models:
                key = f"{path.name}:{key}"
            models[key] = _sized(model)
            bodies[key] = _body_of(model, path, body)
            files[key] = str(path)
    return models, bodies, files


def _fmt(value: Any, spec: str) -> str:
    if value is None:
        return "—"
    return format(value, spec)


CAMERA_ROWS = (
    ("kind", "kind", "s"), ("body", "body", "s"), ("lines", "lines", "d"),
    ("samples", "samples", "d"), ("centre lon °E", "center_lon_deg", ".5f"),
    ("centre lat °", "center_lat_deg", ".5f"), ("GSD m/px", "gsd_m", ".4g"),
    ("GSD line m", "gsd_line_m", ".4g"), ("GSD sample m", "gsd_sample_m", ".4g"),
    ("altitude km", "altitude_km", ".3f"), ("slant range km", "slant_range_km", ".3f"),
    ("emission °", "emission_deg", ".3f"), ("incidence °", "incidence_deg", ".3f"),
    ("phase °", "phase_deg", ".3f"), ("sun azimuth °", "sun_azimuth_deg", ".3f"),
    ("sun elevation °", "sun_elevation_deg", ".3f"), ("footprint km²", "area_km2", ".4g"))
PAIR_COLUMNS = (("convergence °", "convergence_deg", ".3f"), ("B/H", "base_to_height", ".4f"),
                ("base km", "base_km", ".3f"), ("overlap km²", "overlap_area_km2", ".4g"),
                ("overlap 1st", "overlap_fraction_first", ".1%"),
                ("overlap 2nd", "overlap_fraction_second", ".1%"))


def format_table(report: dict[str, Any]) -> str:
    """The report as text: one column per camera, then one line per pair, then notes."""
    cameras = report["cameras"]
    width = max([14, *(len(c["name"]) for c in cameras)]) + 2
    lines = [f"{'':<16}" + "".join(f"{c['name']:>{width}}" for c in cameras)]
    for label, key, spec in CAMERA_ROWS:
        cells = []
        for c in cameras:
            value = {**c, "altitude_km": c.get("altitude_m") and c["altitude_m"] / 1e3,
                     "slant_range_km": c.get("slant_range_m") and c["slant_range_m"] / 1e3,
                     "area_km2": (c.get("footprint") or {}).get("area_km2")}.get(key)
            cells.append(_fmt(value, spec))
        lines.append(f"{label:<16}" + "".join(f"{v:>{width}}" for v in cells))
    if report["pairs"]:
        lines.append("")
        names = [f"{p['first']} / {p['second']}" for p in report["pairs"]]
        first = max(16, *(len(n) for n in names)) + 2
        lines.append(f"{'pair':<{first}}" + "".join(f"{label:>14}"
                                                    for label, _, _ in PAIR_COLUMNS))
        for name, p in zip(names, report["pairs"], strict=True):
            values = {**p, "base_km": p.get("base_m") and p["base_m"] / 1e3}
            lines.append(f"{name:<{first}}" + "".join(
                f"{_fmt(values.get(key), spec):>14}" for _, key, spec in PAIR_COLUMNS))
    notes = [f"{c['name']}: {n}" for c in cameras for n in c["notes"]] + \
        [f"{p['first']} / {p['second']}: {n}" for p in report["pairs"] for n in p["notes"]]
    if notes:
        lines.append("")
        lines.extend(f"note: {n}" for n in notes)
    return "\n".join(lines)


def run_camera(models: Sequence[str | os.PathLike], params: CameraParams | None = None, *,
               out: str | os.PathLike | None = None, as_json: bool = False,
               stream: TextIO | None = None, resolved: dict[str, Any] | None = None,
               footprints: str | os.PathLike | None = None) -> dict[str, Any]:
    """Report what each model sees, and each pair's stereo geometry.

    Reads every MODEL (:func:`demtool.sensors.read_sensors`), calls
    :func:`demtool.camera.info.camera_info`, prints the table (or, with ``as_json``,
    the JSON report) on ``stream`` (default stdout) and, with ``out``, writes the JSON
    report and its sidecar ``<out>.json``; with ``footprints``, the footprints and the
    pairs' overlaps as GeoJSON polygons (:mod:`demtool.camera.footprints`).

    Returns
    -------
    dict
        ``cameras`` and ``pairs`` (keys: docs/stages/camera.md); each camera also
        has ``file``.
    """
    from demtool import io as dio
    from demtool.camera.info import camera_info
    from demtool.camera.params import CameraParams

    params = params or CameraParams()
    run = StageRun("camera", params, resolved=resolved, inputs={"MODEL": list(models)},
                   outputs={"--out": out, "--footprints": footprints,
                            "sidecar": None if out is None else sidecar_path(out)})
    log, provenance = run.log, run.provenance
    body = _named_body(params.body) if params.body is not None else None
    sensors, bodies, files = read_models(models, body)
    log.info("%d camera model(s) from %d file(s)", len(sensors), len(models))
    report = camera_info(sensors, bodies, points_per_edge=params.points_per_edge)
    for entry in report["cameras"]:
        entry["file"] = files[entry["name"]]
    for entry in report["cameras"]:
        for note in entry["notes"]:
            log.info("%s: %s", entry["name"], note)
    text = dio.dumps_json(report) if as_json else format_table(report)
    collection = None
    if footprints is not None:
        from demtool.camera.footprints import footprint_collection

        collection = footprint_collection(report, sensors, bodies)
        for name in collection.get("left_out", []):
            log.warning("%s: a model in a local frame (no body): no lon/lat footprint in %s",
                        name, footprints)
    if out is not None or collection is not None:
        summary = {"cameras": len(report["cameras"]), "pairs": len(report["pairs"])}
        with run.transaction():
            if collection is not None:
                dio.write_json(footprints, collection)
            if out is not None:
                dio.write_json(out, {**report,
                                     "provenance": provenance.record(summary, [out])})
                provenance.write_sidecar(out, summary)
    print(text, file=stream or sys.stdout)
    return report
