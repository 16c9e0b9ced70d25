"""The ``--control-network`` route of ``demtool bundle``: sensor models adjusted on the
measures of an ISIS control network (:mod:`demtool.bundle.network`).

Outputs: ``bundle.npz`` (the adjusted points, local pinholes of the adjusted models) and
its sidecar ``OUT.json`` (the report below), the adjusted models in ``--adjusted-dir``
(ISD JSON for ISDs and cubes, ``.tsai`` for ``.tsai``), the adjusted network
(``--adjusted-network``: adjusted points, their covariance, the measures' residuals and
rejection flags, as jigsaw's ``ONET``), and a report like jigsaw's ``bundleout.txt``
beside OUT (``OUT`` with ``.bundleout.txt``) with a per-point table
(``.points.csv``, jigsaw's ``bundleout_points.csv``).
"""

from __future__ import annotations

import copy
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from demtool.stagerun import StageRun, sidecar_path


def _serial_list(path) -> list[str]:
    from demtool.io.files import require_file

    lines = require_file(path, "serial list").read_text(encoding="utf-8").splitlines()
    return [s.strip() for s in lines if s.strip() and not s.lstrip().startswith("#")]


def _sigmas(params) -> np.ndarray:
    return np.array([params.pointing_sigma * 1e-3] * 3 + [params.angular_rate_sigma * 1e-3] * 3
                    + [params.angular_acceleration_sigma * 1e-3] * 3
                    + [params.position_sigma] * 3)


def report_paths(out) -> tuple[Path, Path]:
    """The text report and the per-point table written beside ``out``."""
    out = Path(out)
    stem = out.with_suffix("")
    return Path(f"{stem}.bundleout.txt"), Path(f"{stem}.points.csv")


def run_bundle_network(sensor_paths: Sequence[Path], network_path, out, params, *,
                       adjusted_dir=None, adjusted_network=None, serials=None,
                       reference_points=None, resolved=None,
                       started: float | None = None) -> dict:
    """Adjust the sensor models on a control network; write the outputs (module
    docstring).  Returns the sidecar summary."""
    from demtool import io as dio
    from demtool.bundle import writeback
    from demtool.bundle.network import adjust_network, image_axes, solve_mask
    from demtool.bundle.network_inputs import build_problem, match_serials
    from demtool.bundle.network_models import (
        CorrectedSensor,
        adjust_isd_timed,
        frame_offset,
    )
    from demtool.bundle.network_report import network_summary, point_rows, text_report
    from demtool.bundle.sensorblock import local_pinhole
    from demtool.errors import InputError, ParameterError
    from demtool.io.controlnet import read_control_network, write_control_network
    from demtool.sensors import read_sensor
    from demtool.sensors.readers import _sniff

    started = time.perf_counter() if started is None else started
    sensor_paths = [Path(p) for p in sensor_paths]
    kinds = []
    for path in sensor_paths:
        dio.require_file(path, "sensor model")
        kind = _sniff(path)
        if kind not in ("isd", "cube", "tsai"):
            raise InputError(f"{path}: a control network adjusts ISDs, ISIS cubes or .tsai "
                             f"models, not {kind}")
        kinds.append(kind)
    adjusted_paths = []
    if adjusted_dir is not None:
        names = [p.stem + (".tsai" if k == "tsai" else ".json")
                 for p, k in zip(sensor_paths, kinds, strict=True)]
        if len(set(names)) != len(names):
            raise ParameterError("--adjusted-dir: two sensor models share a file stem; "
                                 "their adjusted models would overwrite each other")
        adjusted_paths = [Path(adjusted_dir) / n for n in names]
    text_path, points_path = report_paths(out)
    run = StageRun("bundle", params, resolved=resolved,
                   inputs={"--sensors": list(sensor_paths),
                           "--control-network": network_path, "--serials": serials,
                           "--reference-points": reference_points},
                   outputs={"--out": out, "sidecar": sidecar_path(out),
                            "report": [text_path, points_path],
                            "--adjusted-network": adjusted_network,
                            "adjusted models": adjusted_paths or None},
                   folders={"--adjusted-dir": adjusted_dir})
    log, prov = run.log, run.provenance
    network = read_control_network(network_path)
    models = [read_sensor(p) for p in sensor_paths]
    radii = next((m.radii for m in models if m.radii is not None), None)
    for k, kind in enumerate(kinds):
        if kind == "tsai":
            models[k] = read_sensor(sensor_paths[k], radii=radii)
    names = [p.stem for p in sensor_paths]
    explicit = _serial_list(serials) if serials is not None else None
    from demtool.bundle.network_inputs import label_clock

    clocks = [label_clock(p) if k == "cube" else None
              for p, k in zip(sensor_paths, kinds, strict=True)]
    mapping = match_serials(network.serials(), models, names, explicit=explicit,
                            source=str(network_path), label_clocks=clocks)
    unmatched = [s for s in network.serials() if s not in mapping]
    log.info("control network %s: %d points, %d measures; serials matched: %s",
             network.network_id, len(network.points), network.measure_count,
             ", ".join(f"{s} = {names[i]}" for s, i in mapping.items()))
    if unmatched:
        log.warning("%d serial number(s) of the network match no image given; their "
                    "measures are left out: %s", len(unmatched), ", ".join(unmatched[:5]))
    solve = solve_mask(params.solve.split("+") + (["position"] if params.solve_position
                                                  else []))
    problem, point_index, measure_index = build_problem(
        network, models, names, mapping, solve=solve, sigmas=_sigmas(params),
        pixel_sigma=params.measure_sigma, source=str(network_path))
    surface = None
    if reference_points is not None:
        surface = _shot_surface(reference_points, models, params)
        import dataclasses

        problem = dataclasses.replace(problem, reference=surface)
        tied = int(np.count_nonzero(np.isfinite(surface.residuals(problem.points)[0])))
        log.info("reference points: %d shots, reach %.1f m; %d of %d network points over "
                 "them", surface.count, surface.reach, tied, len(problem.points))
        if not tied:
            log.warning("no network point lies within %.1f m of a shot: the shots do not "
                        "control this block", surface.reach)
    measured = sorted(set(problem.observations.image.tolist()))
    if len(measured) < len(models):
        missing = [names[i] for i in range(len(models)) if i not in measured]
        raise InputError(f"{network_path}: no measure in image(s) {', '.join(missing)}; "
                         "give only the network's images (or --serials)")
    solution = adjust_network(problem, rejection_multiplier=params.rejection_multiplier
                              or None)
    frames = [image_axes(m) for m in models]
    corrected = [CorrectedSensor(m, f, t) for m, f, t in
                 zip(models, frames, solution.theta, strict=True)]
    summary = network_summary(problem, solution, names, network, mapping, point_index,
                              measure_index, params)
    if surface is not None:
        dh, sigma = surface.residuals(solution.points)
        on = np.isfinite(dh)
        summary["reference_points"] = {
            "file": str(reference_points), "shots": surface.count, "reach_m": surface.reach,
            "points_tied": int(on.sum()),
            "height_residual_rms_m": float(np.sqrt(np.mean(dh[on] ** 2))) if on.any()
            else None,
            "height_residual_median_m": float(np.median(dh[on])) if on.any() else None}
    log.info("sigma0 %.4f px (%.4f with the prior models), %d degrees of freedom, %d "
             "iterations; %d measure(s) rejected", solution.sigma0, solution.initial_sigma0,
             solution.dof, solution.iterations, len(solution.rejected))
    for name, row in summary["images"].items():
        log.info("  %-32s %4d measures, residual RMS line %.3f sample %.3f px", name,
                 row["measures"], row["rms_line_px"] or float("nan"),
                 row["rms_sample_px"] or float("nan"))
    adjusted_net = _adjusted_network(network, problem, solution, point_index, measure_index)
    from demtool.bundle.model import BundleResult

    obs = problem.observations
    kept = solution.kept
    track = np.bincount(obs.point[kept], minlength=len(problem.points))
    norms = np.linalg.norm(np.nan_to_num(solution.residuals), axis=1)
    errors = np.bincount(obs.point[kept], norms[kept], len(problem.points)) / \
        np.maximum(track, 1)
    cameras = [local_pinhole(c)[0] for c in corrected]
    result = BundleResult(points=solution.points, colors=np.zeros(len(problem.points)),
                          track_length=track.astype(np.int64), reprojection_error=errors,
                          image_names=np.asarray(names, dtype=str), cameras=cameras,
                          distortion=np.zeros((len(names), 2)), target_index=0,
                          aligned=True)
    with run.transaction():
        dio.write_npz(out, "bundle", result.to_arrays())
        outputs = [Path(out)]
        written = {}
        for k, (path, kind, final) in enumerate(zip(sensor_paths, kinds, adjusted_paths
                                                    or [None] * len(kinds), strict=True)):
            if final is None:
                continue
            if kind == "tsai":
                text = writeback.adjust_tsai(path.read_text(encoding="utf-8"),
                                             frame_offset(models[k], frames[k],
                                                          solution.theta[k]),
                                             source=str(path))
            else:
                isd = (json.loads(path.read_text(encoding="utf-8")) if kind == "isd"
                       else writeback.model_isd(models[k]))
                text = writeback.dumps_isd(adjust_isd_timed(
                    isd, frames[k], solution.theta[k],
                    center_time=float(isd["center_ephemeris_time"])))
            with dio.atomic_path(final) as temporary:
                temporary.write_text(text, encoding="utf-8")
            outputs.append(final)
            written[names[k]] = str(final)
        summary["adjusted_models"] = written
        if adjusted_network is not None:
            write_control_network(adjusted_network, adjusted_net)
            outputs.append(Path(adjusted_network))
        with dio.atomic_path(text_path) as temporary:
            temporary.write_text(text_report(summary), encoding="utf-8")
        with dio.atomic_path(points_path) as temporary:
            temporary.write_text(point_rows(summary["points_table"]), encoding="utf-8")
        outputs += [text_path, points_path]
        summary["time_s"] = round(time.perf_counter() - started, 2)
        prov.write_sidecar(out, {k: v for k, v in summary.items() if k != "points_table"},
                           outputs=outputs)
    if not written:
        log.warning("no --adjusted-dir: the adjusted sensor models are not written")
    return summary


def _shot_surface(path, models, params):
    """The :class:`ShotSurface` of an altimetry table, refused when its radii are far
    from the models' body."""
    from demtool.bundle.network_altimetry import ShotSurface
    from demtool.errors import InputError
    from demtool.io.altimetry import BODY_TOLERANCE, read_shots

    shots = read_shots(path)
    radius = next((m.radii[0] for m in models if m.radii is not None), None)
    if radius is None:
        raise InputError(f"{path}: the sensor models give no body radius to place the "
                         "shots on")
    if shots.radius is not None:
        median = float(np.median(shots.radius))
        if abs(median - radius) > BODY_TOLERANCE * radius:
            raise InputError(f"{path}: the shots' radii (median {median / 1e3:.1f} km) are "
                             f"far from the models' body ({radius / 1e3:.1f} km): altimetry "
                             "of another body?")
    return ShotSurface(shots, radius=radius, sigma=params.reference_points_sigma)


def _adjusted_network(network, problem, solution, point_index, measure_index):
    """A copy of the network with jigsaw's outputs: adjusted points and covariances,
    residuals (computed − measured, pixels) and rejection flags of the measures."""
    from demtool.io.controlnet import with_points

    points = [copy.deepcopy(p) for p in network.points]
    for n, p_index in enumerate(point_index):
        point = points[p_index]
        point.adjusted_xyz = solution.points[n].copy()
        cov = solution.point_covariance[n]
        point.adjusted_covariance = None if not np.all(np.isfinite(cov)) else cov.copy()
    rejected = set(solution.rejected)
    for k, (p_index, m_index) in enumerate(measure_index):
        measure = points[p_index].measures[m_index]
        if k in rejected:
            measure.jigsaw_rejected = True
        else:
            measure.line_residual = float(solution.residuals[k, 0])
            measure.sample_residual = float(solution.residuals[k, 1])
            if measure.jigsaw_rejected:
                measure.jigsaw_rejected = False
    return with_points(network, points)


def check_network_options(inputs: Sequence[str | os.PathLike], sensors, image_list,
                          other: dict) -> None:
    """Refuse options that do not apply with ``--control-network``."""
    from demtool.errors import ParameterError

    if not sensors:
        raise ParameterError("--control-network needs the images' sensor models: "
                             "--sensors MODEL, repeated")
    for option, value in other.items():
        if value:
            raise ParameterError(f"{option} does not apply with --control-network")
