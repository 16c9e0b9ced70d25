"""What every stage's runner shares (a runner reads inputs, calls the core, writes outputs).

``demtool.<stage>.run`` holds ``run_<stage>(...)``, the function the click command
``demtool.commands.<stage>`` calls, and the one benchmarks, tests and notebooks call.
Runners never import click.  Each starts by declaring its files in a
:class:`StageRun`, the one place that knows a run's inputs and outputs: it checks
them (:func:`demtool.outputs.check_output_paths`, before any work) and the
parameters, builds the :class:`~demtool.provenance.Provenance`, names the stage's
logger (``demtool.<stage>``) and opens the output transaction with the same
declaration (:meth:`StageRun.transaction`).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

from demtool.errors import InputError
from demtool.logs import get_logger
from demtool.outputs import check_output_paths, output_transaction
from demtool.parameters import Parameters
from demtool.provenance import Provenance
from demtool.stages import STAGES

PathLike = str | os.PathLike
#: one input or output: a path, several paths (a repeatable option), or None (not given)
FileSpec = PathLike | Sequence[PathLike] | None


def _paths(spec: FileSpec) -> list[Path]:
    if spec is None:
        return []
    if isinstance(spec, (str, os.PathLike)):
        return [Path(spec)]
    return [Path(p) for p in spec]


def sidecar_path(output: PathLike) -> Path:
    """The provenance sidecar of an output: ``<output>.json`` (declare it as an output)."""
    return Path(f"{os.fspath(output)}.json")


class StageRun:
    """The files of one stage run, declared in one place at the runner's start.

    Declare **every** file the run writes, the sidecar (:func:`sidecar_path`) and the
    files written into an output folder included, so that a bad path is refused before
    any work; then write them inside ``with run.transaction():``.  With the environment
    variable ``DEMTOOL_CHECK_DECLARED_OUTPUTS`` set (the test suite sets it) a write
    that was not declared is refused.

    Parameters
    ----------
    stage : str
        The stage's name (a key of :data:`demtool.stages.STAGES`).
    params : Parameters
        The stage's parameters, checked here (:meth:`Parameters.check`).
    inputs : mapping
        Option or argument label (``"DEM"``, ``"--rectify"``) → input path(s) or None,
        in the order the provenance lists them.
    outputs : mapping
        Label → output file path(s) or None (not asked for).
    folders : mapping
        Label → output folder(s) or None; files of unknown names may be written in them.
    resolved : mapping, optional
        The command's resolved options, for the provenance record (default:
        ``params.as_dict()``).

    Attributes
    ----------
    provenance : Provenance
        Started now (its clock times the run).
    log : logging.Logger
        The stage's logger, ``demtool.<stage>``.
    timings : dict of str to float
        Seconds per phase timed by :meth:`phase` (for the sidecar's ``timings_s``).

    Raises
    ------
    InputError
        One line naming the path (:func:`demtool.outputs.check_output_paths`): an output
        that is an input or another output (symlinks and hard links followed), an
        output file that is a folder or an output folder that is a file, a folder that
        cannot be created or written.
    ParameterError
        An invalid parameter.
    """

    def __init__(self, stage: str, params: Parameters, *,
                 resolved: Mapping[str, Any] | None = None,
                 inputs: Mapping[str, FileSpec] = {},  # noqa: B006 - read only
                 outputs: Mapping[str, FileSpec] = {},  # noqa: B006
                 folders: Mapping[str, FileSpec] = {}) -> None:  # noqa: B006
        if stage not in STAGES:
            raise KeyError(f"unknown stage {stage!r}")
        params.check()
        self.stage = stage
        self.params = params
        self.log = get_logger(stage)
        self.inputs = {k: _paths(v) for k, v in inputs.items() if v is not None}
        self.outputs = {k: _paths(v) for k, v in outputs.items() if v is not None}
        self.folders = {k: _paths(v) for k, v in folders.items() if v is not None}
        self.check_outputs()
        self.provenance = Provenance(stage, resolved or params.as_dict(), self.input_paths())
        self.timings: dict[str, float] = {}

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Time a phase of the run: ``timings[name]`` wall seconds and
        ``timings[name + "_cpu"]`` CPU seconds of the whole process (every thread), so
        CPU ÷ wall is the cores the phase kept busy.  A phase timed twice adds up."""
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            for key, value in ((name, time.perf_counter() - wall),
                               (f"{name}_cpu", time.process_time() - cpu)):
                self.timings[key] = round(self.timings.get(key, 0.0) + value, 3)

    def input_paths(self) -> list[Path]:
        """Every input path, in declaration order."""
        return [p for paths in self.inputs.values() for p in paths]

    def output_paths(self) -> list[Path]:
        """Every declared output file, in declaration order."""
        return [p for paths in self.outputs.values() for p in paths]

    def check_outputs(self) -> None:
        """Refuse outputs over inputs or each other, misplaced or unwritable (no work done)."""
        check_output_paths(self.inputs, self.outputs, output_dirs=self.folders)

    def transaction(self) -> AbstractContextManager[None]:
        """``io.output_transaction`` over this run's declared inputs, outputs and folders."""
        return output_transaction(self.inputs, self.outputs, output_dirs=self.folders,
                                  declared=True)


def check_same_frame(raster: Any, reference: Any, hint: str, what: str = "the reference"
                     ) -> None:
    """Rasters without CRS must carry the same ``frame`` tag (when both carry one).

    Parameters
    ----------
    raster, reference : demtool.io.Raster
        The two rasters (``path``, ``crs`` and ``tags`` are read).
    hint : str
        What to do about a mismatch, ending the message.
    what : str
        What ``reference`` is, for the message.

    Raises
    ------
    InputError
        Naming ``raster``, both frames and ``reference``.
    """
    frame, other = reference.tags.get("frame"), raster.tags.get("frame")
    if raster.crs is None and reference.crs is None and frame and other and other != frame:
        raise InputError(f"{raster.path}: is in frame '{other}' but {what} {reference.path} "
                         f"is in frame '{frame}'; {hint}")


def check_stereo_pair(left: Any, right: Any, rectify: PathLike | None = None, *,
                      rectification: Mapping[str, Any] | None = None,
                      rectified: bool = True) -> None:
    """What ``sgm`` and ``match`` need of a pair: texture, and a rectify.npz of this pair.

    Parameters
    ----------
    left, right : demtool.io.Raster
        The images as read (``data``, ``path``, ``tags``).
    rectify : path-like, optional
        The pair's ``rectify.npz`` (read here unless ``rectification`` is given).
    rectification : mapping, optional
        Its content, when already read.
    rectified : bool
        Whether the images are the rectified pair (else the originals).

    Raises
    ------
    InputError
        A constant or near-constant image (:func:`demtool.imaging.checks.check_texture`), or a
        rectification of another pair (:func:`demtool.imaging.checks.check_rectification_matches`).
    """
    from demtool import io as dio
    from demtool.imaging import checks

    checks.check_texture(left.data, left.path, what="left image")
    checks.check_texture(right.data, right.path, what="right image")
    if rectify is None or Path(left.path) == Path(right.path):
        return
    content = rectification if rectification is not None else \
        dio.read_npz(rectify, "rectification")
    sources = {left.path: left.tags.get("rectified_from"),
               right.path: right.tags.get("rectified_from")} if rectified else None
    checks.check_rectification_matches(
        content, rectify, {left.path: left.data.shape, right.path: right.data.shape},
        rectified=rectified, sources=sources)
