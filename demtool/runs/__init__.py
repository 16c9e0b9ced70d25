"""Runners: the middle tier of every stage (read inputs, call the core, write outputs).

``demtool.runs.<stage>`` holds ``run_<stage>(...)``, the function the click command
``demtool.commands.<stage>`` calls, and the one benchmarks, tests and notebooks call.
Runners never import click.  Each starts by declaring its files in a
:class:`StageRun`, the one place that knows a run's inputs and outputs: it checks
them and the parameters, builds the :class:`~demtool.provenance.Provenance` and
names the stage's logger (``demtool.<stage>``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from demtool.errors import InputError, ParameterError
from demtool.logs import get_logger
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


class StageRun:
    """The files of one stage run, declared in one place at the runner's start.

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
        Label → output file path or None (not asked for).
    folders : mapping
        Label → output folder or None.

    Attributes
    ----------
    provenance : Provenance
        Started now (its clock times the run).
    log : logging.Logger
        The stage's logger, ``demtool.<stage>``.

    resolved : mapping, optional
        The command's resolved options, for the provenance record (default:
        ``params.as_dict()``).

    Raises
    ------
    InputError
        An output file that is an existing folder, or an output folder that is a file.
    ParameterError
        An invalid parameter, or two outputs that are the same file.
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

    def input_paths(self) -> list[Path]:
        """Every input path, in declaration order."""
        return [p for paths in self.inputs.values() for p in paths]

    def check_outputs(self) -> None:
        """Outputs must be writable as what they are, and distinct from each other."""
        for label, paths in self.folders.items():
            for path in paths:
                if path.exists() and not path.is_dir():
                    raise InputError(f"{path}: {label} must be a folder, but a file of that "
                                     "name exists")
        seen: dict[Path, str] = {}
        for label, paths in self.outputs.items():
            for path in paths:
                if path.is_dir():
                    raise InputError(f"{path}: {label} must be a file name, but it is a "
                                     "folder")
                resolved = path.resolve()
                if resolved in seen:
                    raise ParameterError(f"{label} {path} is the same file as "
                                         f"{seen[resolved]}")
                seen[resolved] = label


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
