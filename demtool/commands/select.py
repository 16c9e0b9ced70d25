"""`demtool select` (not implemented yet)."""

import click

from demtool.cli import STAGES
from demtool.errors import DemtoolError


@click.command(name="select", help=STAGES["select"] + "\n\nNot implemented yet.")
def command() -> None:
    raise DemtoolError("not implemented yet")
