"""``compare --html``: one self-contained page that shows a person the comparison.

``report.html`` holds everything in one file — no script, no stylesheet, font or
image fetched from anywhere: the figures are inline PNGs (``data:image/png;base64``
URIs, RFC 2397), the style an inline ``<style>`` block.  It can be mailed, archived
beside the DEM or opened from a cluster's scratch disk.  Its sections: the inputs and
the comparison grid; the statistics table (the DEM and each ``--also`` DEM, after and
before alignment); the shift (comparison-grid pixels, metres east/north/up, each
input's own pixels, with the 1-σ uncertainties); the slope classes; the effective
resolution; the warnings; the figures; the provenance (demtool version, command,
parameters, the inputs' SHA-256).  Everything comes from ``report.json``'s content,
so the page says no more and no less than the report.
"""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Mapping
from typing import Any

__all__ = ["HTML_REPORT", "html_report"]

#: The page's file name in the report folder.
HTML_REPORT = "report.html"

_CAPTIONS = {
    "difference.png": "Aligned DEM − reference (metres)",
    "dems.png": "The DEMs and the reference (hillshades)",
    "profiles.png": "Profiles",
    "histogram.png": "Histogram of the differences",
    "completeness.png": "Completeness: where the DEM has a value",
    "coherence.png": "Spectral coherence with the reference (effective resolution)",
}

_STYLE = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:2em auto;
max-width:1100px;color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.5em;margin-bottom:.2em}h2{font-size:1.15em;margin-top:1.6em;
border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#f2f2f2}td{white-space:nowrap}td.l,th.l{text-align:left;white-space:normal}
figure{margin:1em 0;display:inline-block;max-width:100%;vertical-align:top}
figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.9em;color:#555}
.warn{background:#fff4e0;border-left:4px solid #e69500;padding:.4em .8em;margin:.3em 0}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.85em}
.muted{color:#666}
"""


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _num(value: Any, spec: str = ".3f") -> str:
    if value is None:
        return "—"
    if isinstance(value, float) and value != value:  # NaN
        return "—"
    try:
        return format(value, spec)
    except (TypeError, ValueError):
        return _e(value)


def _table(header: list[str], rows: list[list[str]], *, left: int = 1,
           table_id: str = "") -> str:
    """An HTML table; cells are already escaped HTML; the first ``left`` columns
    left-aligned."""
    attribute = f' id="{table_id}"' if table_id else ""
    head = "".join(f'<th class="l">{h}</th>' if i < left else f"<th>{h}</th>"
                   for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(f'<td class="l">{c}</td>' if i < left else f"<td>{c}</td>"
                                    for i, c in enumerate(row)) + "</tr>" for row in rows)
    thead = f"<thead><tr>{head}</tr></thead>" if any(header) else ""
    return f"<table{attribute}>{thead}<tbody>{body}</tbody></table>"


_STAT_KEYS = ("count", "completeness", "mean", "median", "std", "rmse", "nmad", "le90", "min",
              "max")
_STAT_HEADER = ["DEM", "n", "complete %", "mean m", "median m", "std m", "RMSE m", "NMAD m",
                "LE90 m", "min m", "max m"]


def _stat_row(label: str, stats: Mapping[str, Any]) -> list[str]:
    cells = [_e(label), _num(stats.get("count"), "d")]
    cells += [_num(stats.get("completeness"), ".2f")]
    cells += [_num(stats.get(k)) for k in _STAT_KEYS[2:]]
    return cells


def _statistics(report: Mapping[str, Any]) -> str:
    rows = [_stat_row(f"{report.get('label')} (aligned)", report)]
    before = report.get("before_alignment") or {}
    if before:
        rows.append(_stat_row(f"{report.get('label')} (before alignment)",
                              {**before, "completeness": report.get("completeness")}))
    for other in report.get("also", []):
        rows.append(_stat_row(f"{other.get('label')} (aligned)", other))
    return _table(_STAT_HEADER, rows, table_id="statistics")


def _shift(report: Mapping[str, Any]) -> str:
    entries = [(report.get("label"), report)] + [(o.get("label"), o)
                                                 for o in report.get("also", [])]
    rows = []
    for label, r in entries:
        shift, sigma = r.get("shift") or {}, r.get("shift_uncertainty") or {}
        rows.append([_e(label), "comparison-grid pixels",
                     f"{_num(shift.get('dx_px'))} ± {_num(sigma.get('dx_px'), '.2g')}",
                     f"{_num(shift.get('dy_px'))} ± {_num(sigma.get('dy_px'), '.2g')}",
                     f"{_num(shift.get('dz'))} ± {_num(sigma.get('dz'), '.2g')}"])
        metres, sigma_m = r.get("shift_m") or {}, r.get("shift_uncertainty_m") or {}
        if metres:
            keys = ("east", "north") if "east" in metres else ("x", "y")
            rows.append([_e(label), f"metres ({_e(metres.get('axes', ''))})",
                         f"{_num(metres.get(keys[0]))} ± {_num(sigma_m.get(keys[0]), '.2g')}",
                         f"{_num(metres.get(keys[1]))} ± {_num(sigma_m.get(keys[1]), '.2g')}",
                         f"{_num(metres.get('up'))} ± {_num(sigma_m.get('up'), '.2g')}"])
        for name, own in (r.get("shift_input_px") or {}).items():
            size = ", ".join(_num(v, ".6g") for v in own.get("pixel_size", []))
            units = f"{_e(name)}'s own pixels ({size} {_e(own.get('pixel_units'))})"
            rows.append([_e(label), units,
                         f"{_num(own.get('dx_px'))} ± {_num(own.get('sigma_dx_px'), '.2g')}",
                         f"{_num(own.get('dy_px'))} ± {_num(own.get('sigma_dy_px'), '.2g')}", "—"])
    note = ("<p class='muted'>The translation that, added to the DEM, aligns it with the "
            "reference (x right / y down in pixels; east, north, up in metres), 1-σ "
            f"uncertainties; alignment <b>{_e((report.get('alignment') or {}).get('method'))}"
            "</b>.</p>")
    return note + _table(["DEM", "units", "x / east", "y / north", "z / up (m)"], rows,
                         left=2, table_id="shift")


def _slopes(report: Mapping[str, Any]) -> str:
    classes = report.get("slope_classes") or []
    if not classes:
        return ""
    rows = [[f"{_num(c.get('slope_min_deg'), 'g')}–{_num(c.get('slope_max_deg'), 'g')}°",
             _num(c.get("count"), "d"), _num(c.get("mean")), _num(c.get("rmse")),
             _num(c.get("nmad"))] for c in classes]
    return "<h2>By slope of the reference</h2>" + _table(
        ["slope", "n", "mean m", "RMSE m", "NMAD m"], rows, table_id="slopes")


def _inputs(report: Mapping[str, Any]) -> str:
    grid = report.get("grid") or {}
    rows = [["DEM", _e(report.get("dem"))], ["reference", _e(report.get("reference"))]]
    rows += [["also", _e(o.get("dem"))] for o in report.get("also", [])]
    shape = grid.get("shape") or []
    spacing = grid.get("spacing_m") or []
    rows += [["comparison grid", _e(f"the {grid.get('on')}'s, {' × '.join(map(str, shape[::-1]))}"
                                    f" cells of {' × '.join(_num(s, '.4g') for s in spacing)} m")],
             ["CRS", _e(grid.get("crs") or "none" + (f" (frame {grid['frame']})"
                                                      if grid.get("frame") else ""))]]
    if grid.get("from_geographic"):
        rows.append(["measured on", _e(grid["from_geographic"].get("projection"))])
    return _table(["", ""], rows, left=2, table_id="inputs")


def _resolution(report: Mapping[str, Any]) -> str:
    resolution = report.get("effective_resolution")
    coarse = report.get("at_reference_resolution")
    parts = []
    if resolution:
        limited = " (Nyquist-limited: coherent up to the grid's limit)" \
            if resolution.get("nyquist_limited") else ""
        parts.append(f"<p>Effective resolution: coherent down to wavelengths of "
                     f"<b>{_num(resolution.get('wavelength_m'), '.4g')} m</b> (coherence "
                     f"{_num(resolution.get('threshold'), 'g')}){_e(limited)}.</p>")
    if coarse:
        parts.append("<p>At the reference's resolution: " + (
            _e(coarse["error"]) if coarse.get("error") else
            f"median {_num(coarse.get('median'))} m, NMAD {_num(coarse.get('nmad'))} m, "
            f"RMSE {_num(coarse.get('rmse'))} m over {_num(coarse.get('count'), 'd')} "
            "posts") + ".</p>")
    return "".join(parts)


def _figures(figures: Mapping[str, bytes]) -> str:
    if not figures:
        return "<p class='muted'>No figures (compare --no-plots).</p>"
    parts = []
    for name, content in figures.items():
        data = base64.b64encode(content).decode("ascii")
        caption = _CAPTIONS.get(name, name)
        parts.append(f'<figure><img alt="{_e(caption)}" data-name="{_e(name)}" '
                     f'src="data:image/png;base64,{data}"><figcaption>{_e(caption)} '
                     f"<span class='muted'>({_e(name)})</span></figcaption></figure>")
    return "".join(parts)


def _provenance(report: Mapping[str, Any]) -> str:
    record = report.get("provenance") or {}
    rows = [[_e(k), _e(record.get(k))] for k in ("demtool_version", "command", "started_utc",
                                                  "wall_time_s", "peak_memory_mb", "python")
            if k in record]
    rows += [[f"input {i + 1}", f"{_e(item.get('path'))}<br><span class='muted'>sha256 "
              f"{_e(item.get('sha256'))}</span>"]
             for i, item in enumerate(record.get("inputs", []))]
    parameters = json.dumps(record.get("parameters", {}), indent=1, sort_keys=True,
                            default=str)
    return (_table(["", ""], rows, left=2, table_id="provenance")
            + f"<p>Parameters:</p><pre>{_e(parameters)}</pre>")


def html_report(report: Mapping[str, Any], figures: Mapping[str, bytes]) -> str:
    """The self-contained HTML page of a comparison.

    Parameters
    ----------
    report : mapping
        What ``compare`` writes to ``report.json`` (with its ``provenance``).
    figures : mapping of file name to PNG bytes
        The figures (``difference.png`` …), embedded as ``data:`` URIs.

    Returns
    -------
    str
        The page (UTF-8 text, no external resource).
    """
    title = f"{report.get('label')} vs {report.get('reference')}"
    warnings = "".join(f"<div class='warn'>{_e(w)}</div>" for w in report.get("warnings", []))
    sections = [
        f"<h1>demtool compare: {_e(title)}</h1>",
        f"<p class='muted'>RMSE <b>{_num(report.get('rmse'))} m</b>, NMAD "
        f"<b>{_num(report.get('nmad'))} m</b>, completeness "
        f"<b>{_num(report.get('completeness'), '.2f')} %</b> over "
        f"{_num(report.get('count'), 'd')} cells.</p>",
        "<h2>Inputs</h2>", _inputs(report),
        "<h2>Statistics of aligned DEM − reference</h2>", _statistics(report),
        "<h2>Shift</h2>", _shift(report), _slopes(report),
        "<h2>Resolution</h2>", _resolution(report) or "<p>—</p>",
        *(["<h2>Warnings</h2>", warnings] if warnings else []),
        "<h2>Figures</h2>", _figures(figures),
        "<h2>Provenance</h2>", _provenance(report),
    ]
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{_e(title)}</title><style>{_STYLE}</style></head><body>"
            + "\n".join(sections) + "</body></html>\n")
