"""`demtool refine` (not implemented yet)."""

import click

from demtool.cli import STAGES
from demtool.errors import DemtoolError


@click.command(name="refine", help=STAGES["refine"] + "\n\nNot implemented yet.")
def command() -> None:
    raise DemtoolError("not implemented yet")
