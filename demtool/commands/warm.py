"""`demtool warm`: compile every cached numba kernel now (:func:`demtool.warm.warm`)."""

from __future__ import annotations

import click

from demtool.cli import TOOLS


@click.command(name="warm", help=TOOLS["warm"] + """

Runs the demo's routes in miniature (every stage, every SGM cost) in a temporary
folder, so each numba kernel compiles once into the cache and a user's first run of a
stage starts as fast as later ones (about 2-5 min on two cores; `make install` runs
it).  The cache: NUMBA_CACHE_DIR when set (point it at a shared, writable folder to
share one cache between users or batch jobs), else beside the installed package when
that is writable, else $XDG_CACHE_HOME/demtool/numba (~/.cache/demtool/numba).
--check only reports which kernels are in the cache.""")
@click.option("--check", is_flag=True, help="Only report which kernels are cached; compile "
                                            "nothing.")
def command(check: bool) -> None:
    """Fill (or with --check, inspect) numba's cache and print one line per step."""
    from demtool import jitcache
    from demtool.warm import coverage, warm

    click.echo(jitcache.describe())
    if not check:
        total = sum(warm(report=lambda step, s: click.echo(f"{s:7.1f} s  {step}")).values())
        click.echo(f"{total:7.1f} s  in all")
    cached, missing = coverage()
    click.echo(f"{len(cached)} of {len(cached) + len(missing)} kernels cached"
               + ("" if not missing else " (not cached: " + ", ".join(missing) + ")"))
