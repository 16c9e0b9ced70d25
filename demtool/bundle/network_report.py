"""The report of a control-network adjustment, like ISIS jigsaw's ``bundleout.txt`` and
``bundleout_points.csv``: σ₀ and the degrees of freedom, per image the measures, the
residual RMS and each parameter's correction and a priori / a posteriori sigma, per
point its residuals and adjusted position, and every rejected measure with its reason.
"""

from __future__ import annotations

import numpy as np

from demtool.bundle.network import PARAMETER_NAMES, PARAMETER_UNITS


def _rms(values) -> float | None:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values ** 2))) if len(values) else None


def _finite(value) -> float | None:
    return float(value) if np.isfinite(value) else None


def network_summary(problem, solution, names, network, mapping, point_index, measure_index,
                    params) -> dict:
    """The sidecar summary (JSON-ready) and the per-point table (``points_table``)."""
    obs = problem.observations
    serial_of = {i: s for s, i in mapping.items()}
    res = solution.residuals
    images = {}
    for i, name in enumerate(names):
        sel = obs.image == i
        kept = sel & solution.kept
        rows = []
        for j, pname in enumerate(PARAMETER_NAMES):
            if not problem.solve[j]:
                continue
            rows.append({"parameter": pname, "unit": PARAMETER_UNITS[j],
                         "correction": float(solution.theta[i, j]),
                         "apriori_sigma": float(problem.sigmas[j]),
                         "adjusted_sigma": _finite(solution.theta_sigma[i, j])})
        images[name] = {
            "serial": serial_of.get(i), "measures": int(np.count_nonzero(sel)),
            "rejected": int(np.count_nonzero(sel & ~solution.kept)),
            "rms_line_px": _rms(res[kept, 0]), "rms_sample_px": _rms(res[kept, 1]),
            "rms_px": _rms(np.linalg.norm(res[kept], axis=1)), "parameters": rows}
    table = []
    for n, p_index in enumerate(point_index):
        point = network.points[p_index]
        sel = np.flatnonzero(obs.point == n)
        kept = sel[solution.kept[sel]]
        xyz = solution.points[n]
        radius = float(np.linalg.norm(xyz))
        cov = solution.point_covariance[n]
        table.append({
            "id": point.id, "type": point.type, "measures": int(len(sel)),
            "rejected": int(len(sel) - len(kept)),
            "rms_residual_px": _rms(np.linalg.norm(res[kept], axis=1)) if len(kept) else None,
            "latitude_deg": float(np.degrees(np.arcsin(xyz[2] / radius))),
            "longitude_deg": float(np.degrees(np.arctan2(xyz[1], xyz[0])) % 360.0),
            "radius_m": radius, "x_m": float(xyz[0]), "y_m": float(xyz[1]),
            "z_m": float(xyz[2]),
            "sigma_m": _finite(np.sqrt(np.trace(cov))) if np.all(np.isfinite(cov)) else None,
            "correction_m": float(np.linalg.norm(xyz - problem.points[n]))})
    rejected = []
    for k, reason in sorted(solution.rejected.items()):
        p_index, m_index = measure_index[k]
        rejected.append({"point": network.points[p_index].id,
                         "serial": network.points[p_index].measures[m_index].serial,
                         "image": names[int(obs.image[k])], "reason": reason})
    kept_res = res[solution.kept]
    return {
        "route": "control network", "network": network.network_id,
        "target": network.target_name, "images_given": list(names),
        "registered": list(names), "not_registered": [], "registered_count": len(names),
        "image_count": len(names), "frame": "body-fixed, metres", "aligned": True,
        "intrinsics": {"mode": "sensor models", "refined": []},
        "solved": [PARAMETER_NAMES[j] for j in range(12) if problem.solve[j]],
        "measure_sigma_px": problem.pixel_sigma,
        "sigma0": solution.sigma0, "initial_sigma0": solution.initial_sigma0,
        "degrees_of_freedom": solution.dof, "iterations": solution.iterations,
        "sigma0_history": solution.history,
        "observations": int(2 * np.count_nonzero(solution.kept)),
        "measures": int(len(obs.image)), "points": int(len(point_index)),
        "points_by_type": {t: int(np.count_nonzero(problem.point_kind == k))
                           for k, t in enumerate(("free", "constrained", "fixed"))},
        "rms_line_px": _rms(kept_res[:, 0]), "rms_sample_px": _rms(kept_res[:, 1]),
        "rms_px": _rms(np.linalg.norm(kept_res, axis=1)),
        "mean_reprojection_error_px": float(np.mean(np.linalg.norm(kept_res, axis=1))),
        "rejected_measures": rejected, "images": images, "points_table": table,
        "residual_convention": "computed minus measured, pixels",
        "rejection_multiplier": params.rejection_multiplier or None,
    }


def text_report(summary: dict) -> str:
    """``bundleout.txt``-like text of :func:`network_summary`."""
    lines = ["JIGSAW-LIKE BUNDLE ADJUSTMENT REPORT (demtool bundle --control-network)", "",
             f"Network: {summary['network']}   Target: {summary['target']}",
             f"Images: {summary['image_count']}   Points: {summary['points']} "
             f"({summary['points_by_type']})   Measures: {summary['measures']}",
             f"Solved per image: {', '.join(summary['solved'])}",
             f"Measure sigma: {summary['measure_sigma_px']:g} px", "",
             f"Sigma0: {summary['sigma0']:.6f} px   (prior models: "
             f"{summary['initial_sigma0']:.6f} px)",
             f"Degrees of freedom: {summary['degrees_of_freedom']}   Iterations: "
             f"{summary['iterations']}",
             f"Residual RMS: line {summary['rms_line_px']:.4f}  sample "
             f"{summary['rms_sample_px']:.4f}  total {summary['rms_px']:.4f} px "
             f"({summary['residual_convention']})", "", "IMAGES", ""]
    for name, row in summary["images"].items():
        lines.append(f"{name}  serial {row['serial']}  measures {row['measures']}  "
                     f"rejected {row['rejected']}  RMS line {row['rms_line_px'] or 0:.4f}  "
                     f"sample {row['rms_sample_px'] or 0:.4f} px")
        lines.append(f"    {'parameter':<28}{'correction':>16}{'a priori sigma':>16}"
                     f"{'adjusted sigma':>16}  unit")
        for p in row["parameters"]:
            adjusted = "N/A" if p["adjusted_sigma"] is None else f"{p['adjusted_sigma']:.6e}"
            lines.append(f"    {p['parameter']:<28}{p['correction']:>16.6e}"
                         f"{p['apriori_sigma']:>16.6e}{adjusted:>16}  {p['unit']}")
        lines.append("")
    lines.append(f"REJECTED MEASURES ({len(summary['rejected_measures'])})")
    for r in summary["rejected_measures"]:
        lines.append(f"    point {r['point']}  {r['serial']} ({r['image']}): {r['reason']}")
    lines.append("")
    return "\n".join(lines)


def point_rows(table: list[dict]) -> str:
    """CSV of the per-point table (``bundleout_points.csv``-like)."""
    if not table:
        return ""
    keys = list(table[0])
    out = [",".join(keys)]
    for row in table:
        out.append(",".join("" if row[k] is None else
                            (f"{row[k]:.6f}" if isinstance(row[k], float) else str(row[k]))
                            for k in keys))
    return "\n".join(out) + "\n"
