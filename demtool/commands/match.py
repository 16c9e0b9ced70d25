"""`demtool match` (not implemented yet)."""

import click

from demtool.cli import STAGES
from demtool.errors import DemtoolError


@click.command(name="match", help=STAGES["match"] + "\n\nNot implemented yet.")
def command() -> None:
    raise DemtoolError("not implemented yet")
