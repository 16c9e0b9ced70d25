"""The ``demtool`` command line: a click group of chained stages.

Each stage (:data:`demtool.stages.STAGES`) lives in ``demtool/commands/<stage>.py``
as a thin click command that resolves options, calls the stage's runner
(``demtool.<stage>.run``) and lets :class:`DemtoolError` reach the group, which
prints it on one line and exits with status 1.  Commands are imported
lazily so ``demtool --help`` stays fast.
"""

from __future__ import annotations

import gc
import importlib
import signal
import sys
from dataclasses import dataclass

import click

from demtool.errors import DemtoolError
from demtool.stages import STAGES

# Commands that are not pipeline stages: name -> one-line description (demtool/commands/<name>.py)
TOOLS: dict[str, str] = {
    "warm": "Compile every numba kernel into the cache now (run once after installing).",
}


@dataclass
class AppState:
    """What the group's options leave for the subcommands (``ctx.obj``)."""

    verbosity: int = 0
    debug: bool = False
    config_path: str | None = None


def load_command(name: str) -> click.Command:
    """Import ``demtool.commands.<name>`` and return its ``command``."""
    module = importlib.import_module(f"demtool.commands.{name}")
    return module.command


def stage_options(name: str) -> list[click.Option] | None:
    """Options of a stage (presets are checked against their types); None for an unknown stage."""
    if name not in STAGES:
        return None
    command = load_command(name)
    return [p for p in command.params if isinstance(p, click.Option) and p.name]


class DemtoolGroup(click.Group):
    """Lazy subcommands; DemtoolError becomes one line on stderr and exit status 1; a
    stage's side threads are joined before the command ends."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return [*STAGES, *TOOLS]

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in STAGES and cmd_name not in TOOLS:
            return None
        return load_command(cmd_name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        with formatter.section("Stages"):
            formatter.write_dl(list(STAGES.items()))
        with formatter.section("Tools"):
            formatter.write_dl(list(TOOLS.items()))

    def invoke(self, ctx: click.Context):
        from demtool.logs import release_warnings

        try:
            try:
                result = super().invoke(ctx)
            except BaseException as exc:
                if not _is_interrupt(exc):  # an interrupt ends the process (daemons)
                    _join_side_threads()
                raise
            _join_side_threads()
        except DemtoolError as exc:
            state = ctx.find_object(AppState)
            release_warnings(show=state is not None and state.debug)
            if state is not None and state.debug:
                raise
            click.echo(f"Error: {_prefix(ctx)}: {exc}", err=True)
            ctx.exit(1)
        except (KeyboardInterrupt, Exception) as exc:
            # an interrupt may surface as another error raised while it unwound: numba's
            # dispatcher wraps it in a SystemError, and a Ctrl-C inside threading's
            # Condition.wait (Dask's as_completed) leaves "cannot release un-acquired
            # lock" (RuntimeError)
            if not _is_interrupt(exc):
                # a usage error is one message too; a bug's traceback keeps its context
                release_warnings(show=not isinstance(exc, click.ClickException))
                raise
            release_warnings(show=False)
            # Outputs were rolled back by io.output_transaction while unwinding.
            click.echo(f"Error: {_prefix(ctx)}: interrupted; no output written", err=True)
            ctx.exit(130)
        except BaseException:  # click's exits (usage errors, --help)
            release_warnings(show=True)
            raise
        release_warnings(show=True)
        return result


def _join_side_threads() -> None:
    """Wait for the threads the stage started beside its work: none outlives the command
    (:mod:`demtool.tiling.side_threads`; not imported, none was started)."""
    side_threads = sys.modules.get("demtool.tiling.side_threads")
    if side_threads is not None:
        side_threads.join_side_threads()


def _prefix(ctx: click.Context) -> str:
    sub = ctx.invoked_subcommand
    return f"demtool {sub}" if sub else "demtool"


def _is_interrupt(exc: BaseException) -> bool:
    """True for Ctrl-C/SIGTERM, also when numba's dispatcher wrapped it in SystemErrors."""
    seen = 0
    current: BaseException | None = exc
    while current is not None and seen < 100:
        if isinstance(current, KeyboardInterrupt):
            return True
        current = current.__cause__ or current.__context__
        seen += 1
    return False


def _print_version(ctx: click.Context, _param: click.Parameter, value: bool) -> None:
    """``demtool --version``: the installed version (read only when asked: see
    :func:`demtool.__getattr__`), in click's ``version_option`` format."""
    if not value or ctx.resilient_parsing:
        return
    import demtool

    click.echo(f"demtool, version {demtool.__version__}")
    ctx.exit()


@click.group(cls=DemtoolGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--version", is_flag=True, expose_value=False, is_eager=True,
              callback=_print_version,
              help="Show the version and exit.")
@click.option("-v", "--verbose", count=True, help="More log output (repeat for more).")
@click.option("-q", "--quiet", count=True, help="Less log output (repeat for less).")
@click.option("--debug", is_flag=True, help="Show full tracebacks on errors.")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help="TOML preset (configs/*.toml); command-line options override it.")
@click.option("--cog", is_flag=True,
              help="Write the stage's rasters as Cloud Optimized GeoTIFFs (GDAL's COG "
                   "driver) instead of tiled GeoTIFFs with internal overviews.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: int, debug: bool, config_path: str | None,
        cog: bool):
    """demtool: Digital Elevation Models of planetary surfaces from spacecraft images.

    Each stage reads and writes files (GeoTIFF, NPZ, JSON), so stages chain in shell
    pipelines, Makefiles and batch jobs.  Run ``demtool STAGE --help`` for a stage.
    """
    from demtool import jitcache
    from demtool.commands.config import load_config, to_default_map
    from demtool.logs import configure_logging, get_logger

    configure_logging(verbose - quiet)
    if not gc.isenabled():  # main() paused it for the imports: what exists now stays
        gc.freeze()
        gc.enable()
    if ctx.invoked_subcommand != "warm" and (unusable := jitcache.unwritable_cache_message()):
        get_logger("demtool").warning(unusable)  # warm refuses such a folder itself
    ctx.obj = AppState(verbosity=verbose - quiet, debug=debug, config_path=config_path)
    if cog:  # for this invocation only (the layout is reset when the context closes)
        from demtool.io.layout import raster_layout

        ctx.with_resource(raster_layout("cog"))
    if config_path:
        content = load_config(config_path)
        ctx.default_map = to_default_map(content, config_path, stage_options)


def _raise_on_sigterm(signum, frame):  # pragma: no cover - exercised through subprocess tests
    raise KeyboardInterrupt(f"terminated by signal {signum}")


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point: SIGTERM unwinds like Ctrl-C so no partial output stays."""
    from demtool.logs import route_library_warnings

    # The cycle collector would traverse the objects of the imports (numpy, numba,
    # rasterio: a few 10^4) several times over, 5 % of a small stage's run.  The group
    # callback freezes them and turns it back on: the stage's own objects are collected.
    gc.disable()
    signal.signal(signal.SIGTERM, _raise_on_sigterm)
    route_library_warnings()  # numpy & co. to the log (-v), not raw on stderr
    try:
        cli.main(args=argv, prog_name="demtool")
    finally:  # --help and usage errors end before the group callback
        gc.enable()
        # What is alive now lives until the process exits.  Frozen, the interpreter's
        # shutdown skips it in its full collections (several, while it clears the
        # modules): after a stage that used numba they traversed its typing registries
        # for ~0.4 CPU s on one core, at the end of every run.
        gc.freeze()


if __name__ == "__main__":  # pragma: no cover
    main()
