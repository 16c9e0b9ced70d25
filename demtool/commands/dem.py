"""`demtool dem` (not implemented yet)."""

import click

from demtool.cli import STAGES
from demtool.errors import DemtoolError


@click.command(name="dem", help=STAGES["dem"] + "\n\nNot implemented yet.")
def command() -> None:
    raise DemtoolError("not implemented yet")
