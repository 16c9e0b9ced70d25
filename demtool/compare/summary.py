"""Print one table summarising several ``compare`` reports (the demo's last word).

Usage: ``python -m demtool.compare.summary REPORT.json ...`` — one row per product with its
RMSE, NMAD, completeness and the highest frequency at which the DEM stays coherent
with the reference.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from demtool import io as dio
from demtool.errors import DemtoolError


def _lookup(report: dict[str, Any], key: str) -> Any:
    """A value by dotted path into nested dicts (``effective_resolution.wavelength_m``)."""
    value: Any = report
    for part in key.split("."):
        if not isinstance(value, dict) or part not in value:
            return None
        value = value[part]
    return value


def _fmt(value: Any, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def summary_rows(reports: Sequence[str | Path]) -> list[dict[str, Any]]:
    """One dict per report: product name and its headline figures."""
    rows = []
    for path in reports:
        report = dio.read_json(path, "comparison report")
        rows.append({
            "product": _lookup(report, "label") or Path(path).parent.name,
            "rmse": _lookup(report, "rmse"),
            "nmad": _lookup(report, "nmad"),
            "completeness": _lookup(report, "completeness"),
            "coherent_wavelength_m": _lookup(report, "effective_resolution.wavelength_m"),
        })
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    """Plain-text table of :func:`summary_rows`."""
    header = (f"{'product':<22} {'RMSE (m)':>9} {'NMAD (m)':>9} {'complete %':>10} "
              f"{'coherent λ (m)':>15}")
    lines = [header, "-" * len(header)]
    for row in rows:
        lines.append(f"{row['product']:<22} {_fmt(row['rmse'], '9.3f')} "
                     f"{_fmt(row['nmad'], '9.3f')} {_fmt(row['completeness'], '10.1f')} "
                     f"{_fmt(row['coherent_wavelength_m'], '15.2f')}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        print("usage: python -m demtool.compare.summary REPORT.json ...", file=sys.stderr)
        return 2
    try:
        print(format_table(summary_rows(args)))
    except DemtoolError as exc:
        print(f"Error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
