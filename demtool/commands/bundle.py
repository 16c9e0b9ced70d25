"""`demtool bundle` (not implemented yet)."""

import click

from demtool.cli import STAGES
from demtool.errors import DemtoolError


@click.command(name="bundle", help=STAGES["bundle"] + "\n\nNot implemented yet.")
def command() -> None:
    raise DemtoolError("not implemented yet")
