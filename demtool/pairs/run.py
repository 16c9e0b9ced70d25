"""Runner of ``demtool pairs``: sensor models in, the stereo pairs worth matching out.

Reads the models as ``demtool camera`` does (:func:`demtool.camera.run.read_models`),
measures every pair (:func:`demtool.camera.info.camera_info`), judges them
(:func:`demtool.pairs.core.pair_verdicts`) and prints a table of every pair (kept or
why not) on stdout, or the JSON report with ``as_json``.  ``out`` writes the kept pairs,
one per line as ``LEFT RIGHT`` (the models' names: an ISD's file stem, the view names
of the images beside them), best first — a list a Makefile or a shell loop reads
(``while read left right; do …; done < pairs.txt``) — with its sidecar.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, TextIO

from demtool.stagerun import StageRun, sidecar_path

if TYPE_CHECKING:
    from demtool.pairs.params import PairsParams


def _fmt(value: Any, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def format_table(verdicts: Sequence[dict[str, Any]], chosen: Sequence[dict[str, Any]]) -> str:
    """One line per pair: its figures and ``kept #rank`` or why it was left out."""
    rank = {(v["first"], v["second"]): i + 1 for i, v in enumerate(chosen)}
    names = [f"{v['first']} {v['second']}" for v in verdicts]
    first = max(16, *(len(n) for n in names)) + 2
    lines = [f"{'pair':<{first}}{'overlap':>9}{'conv °':>9}{'B/H':>7}{'sun Δ°':>8}"
             f"{'score':>7}  verdict"]
    for name, v in zip(names, verdicts, strict=True):
        key = (v["first"], v["second"])
        verdict = f"kept #{rank[key]}" if key in rank else \
            ("; ".join(v["reasons"]) or "not among the best --max-pairs")
        lines.append(f"{name:<{first}}{_fmt(v['overlap'], '.0%'):>9}"
                     f"{_fmt(v['convergence_deg'], '.1f'):>9}"
                     f"{_fmt(v['base_to_height'], '.2f'):>7}"
                     f"{_fmt(v['sun_difference_deg'], '.1f'):>8}{v['score']:>7.3f}  {verdict}")
    return "\n".join(lines)


def run_pairs(models: Sequence[str | os.PathLike], params: PairsParams | None = None, *,
              out: str | os.PathLike | None = None, as_json: bool = False,
              stream: TextIO | None = None, resolved: dict[str, Any] | None = None
              ) -> dict[str, Any]:
    """Choose the stereo pairs of a block (see the module docstring).

    Returns
    -------
    dict
        ``pairs``: every pair's verdict (:func:`demtool.pairs.core.pair_verdicts`);
        ``chosen``: the kept pairs as ``[first, second]``, best first.

    Raises
    ------
    InputError
        Fewer than two models, or no pair passes (the table says why for each).
    """
    from demtool import io as dio
    from demtool.camera.info import camera_info
    from demtool.camera.run import _named_body, read_models
    from demtool.errors import InputError
    from demtool.pairs.core import pair_verdicts, select_pairs
    from demtool.pairs.params import VERDICTS, PairsParams

    params = params or PairsParams()
    run = StageRun("pairs", params, resolved=resolved, inputs={"MODEL": list(models)},
                   outputs={"--out": out,
                            "sidecar": None if out is None else sidecar_path(out)})
    log = run.log
    body = _named_body(params.body) if params.body is not None else None
    sensors, bodies, _ = read_models(models, body)
    if len(sensors) < 2:
        raise InputError(f"{len(sensors)} sensor model(s) in {', '.join(map(str, models))}: "
                         "a block needs at least two")
    report = camera_info(sensors, bodies, points_per_edge=params.points_per_edge)
    options = {k: getattr(params, k) for k in VERDICTS}
    verdicts = pair_verdicts(report["cameras"], report["pairs"], **options)
    chosen = select_pairs(verdicts, params.max_pairs)
    table = format_table(verdicts, chosen)
    log.info("%d model(s), %d pair(s) measured, %d kept", len(sensors), len(verdicts),
             len(chosen))
    if not chosen:
        for line in table.splitlines():  # why, pair by pair: the log (hidden by -q)
            log.info("%s", line)
        reasons = [r.split(" ")[0] for v in verdicts for r in v["reasons"]]
        common = max(set(reasons), key=reasons.count) if reasons else None
        raise InputError(f"no pair of the {len(sensors)} models passes the limits ("
                         f"{len(verdicts)} pair(s)"
                         + (f"; most often left out by {common}" if common else "")
                         + "; the log's table says why for each); widen --min-overlap, "
                         "--min/--max-convergence, --min/--max-bh or --max-sun-difference")
    result = {"pairs": verdicts, "chosen": [[v["first"], v["second"]] for v in chosen]}
    if out is not None:
        summary = {"models": len(sensors), "pairs": len(verdicts), "chosen": result["chosen"]}
        with run.transaction():
            with dio.atomic_path(out, suffix=".txt") as temporary:
                temporary.write_text("".join(f"{a} {b}\n" for a, b in result["chosen"]),
                                     encoding="utf-8")
            run.provenance.write_sidecar(out, summary)
    print(dio.dumps_json(result) if as_json else table, file=stream or sys.stdout)
    return result
