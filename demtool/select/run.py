"""Runner of ``demtool select``: choose the images that overlap a target image."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from demtool.errors import InputError, ProcessingError
from demtool.stagerun import StageRun, sidecar_path
from demtool.synth.folder import read_scene_description, scene_sun_vector

if TYPE_CHECKING:
    from demtool.select.params import SelectParams

DEFAULT_CACHE_NAME = ".demtool-features"


def _load_geometry_sources(cameras_path, scene_path):
    """Cameras by name (from cameras.npz) and the scene's sun vector (from scene.json)."""
    from demtool import io as dio
    from demtool.sensors.pinhole import cameras_from_arrays

    cameras = {}
    if cameras_path is not None:
        cameras = cameras_from_arrays(dio.read_npz(cameras_path, "cameras"))
    sun = None
    if scene_path is not None:
        sun = scene_sun_vector(read_scene_description(scene_path))
    return cameras, sun


def _camera_from_tags(raster, path=None):
    """The sensor model an image's tags name, or None: its ``camera`` tag (a local-frame
    pinhole written by synth), else its ``sensor_model`` tag (an ISD or other model file
    beside the image, read by :func:`demtool.sensors.read_sensor`)."""
    from demtool.sensors import PinholeCamera, read_sensor

    value = raster.tag_json("camera")
    if isinstance(value, dict):
        try:
            return PinholeCamera(K=value["K"], R=value["R"], t=value["t"],
                                 width=value["width"], height=value["height"])
        except (KeyError, TypeError, ValueError):
            return None
    model = raster.tag_json("sensor_model") if path is not None else None
    if model:
        return read_sensor(Path(path).parent / str(model))
    return None


def _sun_from_tags(raster, default, camera=None, point=None):
    """Unit vector toward the sun: from a planetary sensor model's sun position at the
    exposure that sees ``point`` (body-fixed), else the image's ``sun_vector`` tag (local
    frame), else ``default``."""
    import numpy as np

    if camera is not None and camera.radii is not None and point is not None:
        line, _ = camera.ground_to_image(point)
        line = float(line) if np.isfinite(line) else 0.5 * camera.lines
        sun = np.asarray(camera.sun_position(np.asarray(line)), np.float64).reshape(3) - point
        return sun / np.linalg.norm(sun)
    value = raster.tag_json("sun_vector")
    try:
        return np.asarray(value, np.float64).reshape(3) if value is not None else default
    except (TypeError, ValueError):
        return default


def _format_table(rows: list[dict[str, Any]]) -> str:
    """Plain text table of the per-image figures (for the INFO log)."""
    header = f"{'image':<20} {'matches':>7} {'inliers':>7} {'overlap':>7} {'conv°':>6} " \
             f"{'score':>6}  status"
    lines = [header]
    for row in rows:
        conv = row.get("convergence_deg")
        score = row.get("score")
        status = "selected" if row["selected"] else f"rejected: {row['reason']}"
        lines.append(f"{row['name'][:20]:<20} {row.get('matches', 0):>7} "
                     f"{row.get('inliers', 0):>7} {row.get('overlap', 0.0):>7.2f} "
                     f"{'-' if conv is None else format(conv, '.1f'):>6} "
                     f"{'-' if score is None else format(score, '.3f'):>6}  {status}")
    return "\n".join(lines)


def _nothing_selected(records: list[dict[str, Any]], target: str | os.PathLike,
                      min_matches: int, min_inliers: int) -> NoReturn:
    """Raise the error when no candidate passes: unreadable files named as such (a
    missing or corrupt image is not a question of overlap), else the best-matched
    candidate."""
    unreadable = [r for r in records if "error" in r]
    readable = [r for r in records if "error" not in r]
    first = unreadable[0]["error"] if unreadable else ""
    more = f" (and {len(unreadable) - 1} more unreadable)" if len(unreadable) > 1 else ""
    if not readable:
        raise InputError(f"no candidate image could be read: {first}{more}")
    best = max(readable, key=lambda r: (r.get("inliers", 0), r.get("matches", 0)))
    skipped = (f"; {len(unreadable)} unreadable, e.g. {first}" if unreadable else "")
    raise ProcessingError(
        f"no image passes the selection against {target}: {len(records)} candidate(s), "
        f"best {best['name']} with {best.get('matches', 0)} matches and "
        f"{best.get('inliers', 0)} inliers (need >= {min_matches} matches, "
        f">= {min_inliers} inliers){skipped}; lower --min-matches or check the images overlap")


def run_select(images: list[str], target: str, out: str | os.PathLike,
               params: SelectParams | None = None, *,
               roi: tuple[float, float, float, float] | None = None,
               cameras: str | None = None, scene: str | None = None,
               cache_dir: str | None = None,
               resolved: dict[str, Any] | None = None) -> dict[str, Any]:
    """Compare every image with the target and write ``selection.json``.

    ``roi`` (x0, y0, x1, y1, target pixels) limits the target's features;
    ``cameras``/``scene`` give the viewing geometry; features are cached in
    ``cache_dir`` (default ``.demtool-features`` beside ``out``) unless
    ``params.no_cache``.

    Returns
    -------
    dict
        The content written to ``out`` (see CONTRIBUTING.md, "selection.json").
    """
    from concurrent.futures import ThreadPoolExecutor, as_completed

    import numpy as np

    from demtool import io as dio
    from demtool.errors import ParameterError
    from demtool.imaging import features
    from demtool.imaging.feature_cache import FeatureCache
    from demtool.logs import progress
    from demtool.select import core as selection
    from demtool.select.params import SelectParams

    params = params or SelectParams()
    min_matches, min_inliers, seed = params.min_matches, params.min_inliers, params.seed
    out = Path(out)
    target_image = dio.read_image(target, what="target image")
    target_resolved = Path(target).resolve()
    candidates: list[str] = []
    seen = {target_resolved}
    for path in images:
        absolute = Path(path).resolve()
        if absolute not in seen:
            seen.add(absolute)
            candidates.append(path)
    if not candidates:
        raise ParameterError("no candidate image besides the target; give the images to "
                             "compare with the target as IMAGES")
    stems: dict[str, str] = {}
    for path in [target, *candidates]:
        stem = Path(path).stem
        if stem in stems:
            raise ParameterError(f"two images share the name '{stem}' ({stems[stem]} and {path}); "
                                 "views are identified by file stem, rename one")
        stems[stem] = path
    region = selection.check_roi(roi, target_image.data.shape, what=f"target {target}")
    run = StageRun("select", params, resolved=resolved,
                   inputs={"--target": target, "IMAGES": candidates, "--cameras": cameras,
                           "--scene": scene},
                   outputs={"--out": out, "sidecar": sidecar_path(out)})
    log, provenance = run.log, run.provenance
    camera_by_name, scene_sun = _load_geometry_sources(cameras, scene)
    target_name = Path(target).stem
    target_camera = (camera_by_name.get(target_name)
                     or _camera_from_tags(target_image, target))
    if cameras is not None and target_name not in camera_by_name:
        raise InputError(f"{cameras}: has no camera for the target '{target_name}' "
                         f"(cameras: {', '.join(sorted(camera_by_name)) or 'none'})")
    point = None
    if target_camera is not None:
        point = selection.surface_point(target_camera, region.centre)
    target_sun = _sun_from_tags(target_image, scene_sun, target_camera, point)

    cache = FeatureCache(None if params.no_cache else
                         (cache_dir or out.parent / DEFAULT_CACHE_NAME))
    sift = {"max_features": params.max_features,
            "contrast_threshold": params.contrast_threshold}

    def detect(image, **extra):
        return features.detect_sift(image, **sift, **extra)

    target_crop = target_image.data[region.y0:region.y1, region.x0:region.x1]
    target_features = cache.get_or_compute(
        target, {**sift, "roi": region.as_list()},
        lambda: detect(target_crop, offset=(region.x0, region.y0)))
    log.info("target %s: %d SIFT keypoints in the ROI %s", target_name, len(target_features),
             region.as_list())
    if len(target_features) < min_matches:
        raise ProcessingError(f"{target}: only {len(target_features)} SIFT keypoints in the "
                              f"ROI {region.as_list()}, fewer than --min-matches {min_matches}; "
                              "choose a larger or more textured ROI")

    def examine(path: str) -> dict[str, Any]:
        name = Path(path).stem
        record: dict[str, Any] = {"name": name, "path": path}
        try:
            raster = dio.read_image(path, what="image")
        except InputError as exc:
            return {**record, "selected": False, "reason": f"unreadable ({exc})",
                    "error": str(exc), "matches": 0, "inliers": 0, "overlap": 0.0}
        found = cache.get_or_compute(path, sift, lambda: detect(raster.data))
        height, width = raster.data.shape
        match = selection.compare_with_target(
            target_features, found, roi=region, candidate_size=(width, height),
            ratio=params.ratio, min_matches=min_matches, min_inliers=min_inliers,
            min_overlap=params.min_overlap, ransac_threshold=params.ransac_threshold,
            seed=seed)
        record.update(selected=match.accepted, reason=match.reason, keypoints=match.keypoints,
                      matches=match.matches, inliers=match.inliers,
                      overlap=round(match.overlap, 4),
                      inlier_coverage=round(match.inlier_coverage, 4))
        camera = camera_by_name.get(name) or _camera_from_tags(raster, path)
        geometry = None
        if point is not None and camera is not None:
            geometry = selection.view_geometry(target_camera, camera, point,
                                               _sun_from_tags(raster, scene_sun, camera,
                                                              point))
            record.update(geometry.as_dict())
        if params.rank and match.accepted:
            target_azimuth = (None if target_sun is None else
                              float(np.degrees(np.arctan2(target_sun[0], target_sun[1])) % 360))
            score, terms = selection.rank_score(match, geometry, min_matches=min_matches,
                                                target_sun_azimuth_deg=target_azimuth)
            record.update(score=round(score, 4), score_terms=terms)
        return record

    n_workers = params.workers or os.cpu_count() or 1
    records: list[dict[str, Any]] = []
    with ThreadPoolExecutor(max_workers=n_workers) as pool:
        futures = [pool.submit(examine, path) for path in candidates]
        for future in progress(as_completed(futures), "select", total=len(futures)):
            records.append(future.result())
    order = {path: i for i, path in enumerate(candidates)}
    records.sort(key=lambda r: order[r["path"]])
    chosen = [r for r in records if r["selected"]]
    rejected = [r for r in records if not r["selected"]]
    if params.rank:
        chosen.sort(key=lambda r: -r.get("score", 0.0))
        for position, record in enumerate(chosen, start=1):
            record["rank"] = position
    log.info("%d candidate(s) compared with %s (feature cache: %d hit(s), %d miss(es))\n%s",
             len(records), target_name, cache.hits, cache.misses, _format_table(records))
    if not chosen:
        _nothing_selected(records, target, min_matches, min_inliers)
    target_entry: dict[str, Any] = {
        "name": target_name, "path": target, "role": "target",
        "keypoints": len(target_features), "matches": len(target_features),
        "inliers": len(target_features), "overlap": 1.0, "inlier_coverage": 1.0,
    }
    if point is not None:
        target_entry.update(selection.view_geometry(target_camera, target_camera, point,
                                                    target_sun).as_dict())
    for record in chosen:
        record.pop("selected", None)
        record.pop("reason", None)
    for record in rejected:
        record.pop("selected", None)
        record.pop("error", None)  # kept for the message above; its reason says it
    # Paths relative to the selection file's folder, so `bundle` finds them from anywhere.
    for record in [target_entry, *chosen, *rejected]:
        record["path"] = selection.path_relative_to(record["path"], Path(out).parent)
    result = {
        "target": {"name": target_name, "path": target_entry["path"]},
        "roi": None if roi is None else region.as_list(),
        "selected": [target_entry, *chosen],
        "rejected": rejected,
        "parameters": provenance.params,
    }
    summary = {"candidates": len(records), "selected": len(chosen), "rejected": len(rejected),
               "target_keypoints": len(target_features), "cache_hits": cache.hits,
               "cache_misses": cache.misses, "geometry": point is not None}
    with run.transaction():
        dio.write_json(out, result)
        provenance.write_sidecar(out, summary)
    log.info("selected %d of %d image(s) for target %s", len(chosen), len(records), target_name)
    return result
