"""`demtool rectify` (not implemented yet)."""

import click

from demtool.cli import STAGES
from demtool.errors import DemtoolError


@click.command(name="rectify", help=STAGES["rectify"] + "\n\nNot implemented yet.")
def command() -> None:
    raise DemtoolError("not implemented yet")
