"""Option decorators shared by several stages, so they read the same everywhere."""

from __future__ import annotations

import click


def out_file(help_text: str = "Output file.") -> click.decorators.FC:
    """``--out PATH`` (required): the stage's main output file."""
    return click.option("--out", "out", required=True, type=click.Path(dir_okay=False),
                        help=help_text)


def out_dir(help_text: str = "Output folder (created if needed).") -> click.decorators.FC:
    """``--out DIR`` (required): the folder the stage writes into."""
    return click.option("--out", "out", required=True, type=click.Path(file_okay=False),
                        help=help_text)


def input_file(name: str, **kwargs) -> click.decorators.FC:
    """A positional input file; existence is checked by the runner (one clear message)."""
    return click.argument(name, type=click.Path(dir_okay=False), **kwargs)


def seed() -> click.decorators.FC:
    """``--seed N``: seed of every random choice (RANSAC, noise), for reproducible runs."""
    return click.option("--seed", type=int, default=0, show_default=True,
                        help="Random seed, for reproducible runs.")


def workers() -> click.decorators.FC:
    """``--workers N``: threads for parallel work (0 = all cores)."""
    return click.option("--workers", type=click.IntRange(min=0), default=0, show_default=True,
                        help="Parallel workers (0 = all cores).")


def resolved_params(ctx: click.Context) -> dict:
    """The command's parameters after config preset and command line (for provenance)."""
    return dict(ctx.params)
