"""`demtool pairs`: the options of :class:`demtool.pairs.params.PairsParams` and one call."""

from __future__ import annotations

from typing import Any

import click

from demtool.commands import options
from demtool.pairs.params import PairsParams
from demtool.stages import STAGES


@click.command(name="pairs", help=STAGES["pairs"] + """

MODEL...: the block's sensor models (ALE ISD JSON, ISIS3 cube with SPICE, .tsai with
--body, cameras.npz or bundle.npz), as `demtool camera` reads them.  Prints one line per
pair (overlap, convergence, B/H, sun difference, score, kept or why not) on stdout, or
the JSON report with --json.  --out writes the kept pairs best first, one per line as
"LEFT RIGHT" (model names), for a Makefile or a shell loop to run rectify → sgm → dem
per pair and `demtool fuse` at the end.""")
@options.sensor_models()
@options.parameter_options(PairsParams)
@options.json_report_option()
@options.path_option("--out", "Write the kept pairs to this file, one \"LEFT RIGHT\" a line.")
@click.pass_context
def command(ctx: click.Context, models: tuple[str, ...], as_json: bool, out: str | None,
            **values: Any) -> None:
    """Options → PairsParams → :func:`demtool.pairs.run.run_pairs`."""
    from demtool.pairs.run import run_pairs

    run_pairs(models, PairsParams.from_options(values), out=out, as_json=as_json,
              resolved=options.resolved_params(ctx))
