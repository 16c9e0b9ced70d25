"""The stages of bench/scale_out.py: how each makes its inputs and runs untiled and in tiles.

A case (:class:`ScaleCase`) is one stage's row set: its inputs made once (synthetic, with
known truth where the stage has one; sizes from ``--size``), the command that writes its
output untiled, the sidecar phases whose cores (CPU ÷ wall) are reported, the quality
of an output against the truth, and the agreement of a tiled output with the untiled
one.  bench/scale_out.py runs every case three times, each a child process measured by
bench/scale.py's ``run_measured`` (wall, CPU and peak of the whole process tree):
untiled, with ``--tile-size T --workers 1`` and with ``--workers 2`` (threads of the
command's process; with ``--processes`` also a local Dask cluster), and records each
stage's table in its own ``bench/results/<result>.json``.

Adding a stage's case (refine, fuse and compare are in bench/_scale_products.py):

1. write ``prepare(folder, size) -> dict`` (paths of its inputs and truth; run any
   upstream stage here, once), ``command(inputs, out) -> list[str]`` (the untiled
   command line writing ``out``; the tile options are appended to it),
   ``quality(inputs, out) -> dict[str, str]`` (columns against the truth, formatted)
   and ``agreement(inputs, untiled, tiled) -> str`` (e.g. :func:`raster_agreement`);
2. call :func:`register` with a :class:`ScaleCase` naming the stage (the
   ``--stage`` value), its result file (``53_scale_out_<stage>``: every scale-out table
   has order 53), the sidecar phases to report (keys of the sidecar's
   ``timings_s`` with a ``<phase>_cpu`` partner, :func:`phase_seconds`) and a default
   tile size;
3. ``python bench/scale_out.py --stage <name> --size 512`` to try it.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEMTOOL = str(Path(sys.executable).with_name("demtool"))


@dataclass(frozen=True)
class ScaleCase:
    """One stage of bench/scale_out.py (see the module docstring).

    Attributes
    ----------
    stage : str
        The ``--stage`` value.
    result : str
        Its result file's stem, ``bench/results/<result>.json``.
    title : callable (size, tile) -> str
        The table's title.
    prepare : callable (folder, size) -> dict
        Makes the inputs once in ``folder``; returns what ``command``, ``quality`` and
        ``agreement`` need (paths, truth).
    command : callable (inputs, out) -> list[str]
        The untiled command line writing ``out``.
    quality : callable (inputs, out) -> dict[str, str]
        Columns of one output against the truth (formatted), in a fixed order.
    agreement : callable (inputs, untiled, tiled) -> str
        The tiled output against the untiled one, in words and numbers.
    phases : tuple of str
        Sidecar phases whose cores (CPU ÷ wall) are shown for the untiled run.
    tile_size : int
        Default ``--tile-size`` of the tiled runs; 0: the stage has no worker processes,
        only its untiled run is measured.
    untiled_options : callable (tile) -> tuple of str
        Options of the untiled run that depend on the tile size (mapproject's untiled
        loop also works in map tiles: the same ones, so its output can equal the
        engine's).
    suffix : str
        The output file's suffix ("": the output is a folder).
    sidecar : str
        The sidecar's name inside an output folder ("": ``<out>.json``).
    untiled_label : str
        The first run's name in the table (compare's windowed case: "windowed").
    """

    stage: str
    result: str
    title: Callable[[int, int], str]
    prepare: Callable[[Path, int], dict]
    command: Callable[[dict, Path], list[str]]
    quality: Callable[[dict, Path], dict[str, str]]
    agreement: Callable[[dict, Path, Path], str]
    phases: tuple[str, ...] = ()
    tile_size: int = 1024
    untiled_options: Callable[[int], tuple[str, ...]] = lambda tile: ()
    suffix: str = ".tif"
    sidecar: str = ""
    untiled_label: str = "untiled"


CASES: dict[str, ScaleCase] = {}


def register(case: ScaleCase) -> ScaleCase:
    """Add a case to the registry (its ``stage`` must be new)."""
    if case.stage in CASES:
        raise ValueError(f"scale-out case {case.stage!r} registered twice")
    CASES[case.stage] = case
    return case


def phase_seconds(sidecar: dict, phases: tuple[str, ...]) -> dict:
    """The first mapping in a sidecar that holds every phase of ``phases`` and its
    ``<phase>_cpu`` (wall and CPU seconds; ``timings_s`` in demtool's sidecars)."""
    stack = [sidecar]
    while stack:
        item = stack.pop()
        if isinstance(item, dict):
            if phases and all(p in item and f"{p}_cpu" in item for p in phases):
                return item
            stack.extend(item.values())
        elif isinstance(item, list):
            stack.extend(item)
    return {}


def raster_agreement(untiled: Path, tiled: Path, tolerance: float, unit: str) -> str:
    """"identical", or the share of cells within ``tolerance`` and the largest
    difference; NaN cells must match."""
    from demtool import io as dio

    a = dio.read_raster(untiled).data.astype(np.float64)
    b = dio.read_raster(tiled).data.astype(np.float64)
    if a.shape != b.shape:
        return f"shapes differ: {a.shape} vs {b.shape}"
    same_nan = np.isnan(a) == np.isnan(b)
    both = ~np.isnan(a) & ~np.isnan(b)
    diff = np.abs(a - b)[both]
    if same_nan.all() and not diff.any():
        return "identical"
    within = float((diff <= tolerance).mean()) if diff.size else 1.0
    worst = float(diff.max()) if diff.size else 0.0
    return (f"{100 * within:.2f} % within {tolerance:g} {unit} (max {worst:.3g}), "
            f"NaN masks {100 * same_nan.mean():.3f} % equal")


# --- sgm: census and default cost on the synthetic rectified pair -----------------------

def _sgm_prepare(folder: Path, size: int) -> dict:
    from bench._scale_pairs import write_pair

    left, right, truth = write_pair(folder, size)
    return {"left": left, "right": right, "truth": truth}


def _sgm_command(*cost: str) -> Callable[[dict, Path], list[str]]:
    def command(inputs: dict, out: Path) -> list[str]:
        return [DEMTOOL, "sgm", str(inputs["left"]), str(inputs["right"]), "--out", str(out),
                *cost, "--min-disparity", "0", "--num-disparities", "96"]
    return command


def _sgm_quality(inputs: dict, out: Path) -> dict[str, str]:
    from bench.scale import bad2
    from demtool import io as dio

    error, _ = bad2(dio.read_raster(out).data, np.load(inputs["truth"]))
    return {"bad-2 %": f"{100 * error:.2f}"}


def _sgm_agreement(inputs: dict, untiled: Path, tiled: Path) -> str:
    return raster_agreement(untiled, tiled, 0.01, "px")


for _stage, _cost, _label in (("sgm-census", ("--cost", "census"), "census"),
                              ("sgm-default", (), "default cost")):
    register(ScaleCase(
        stage=_stage, result="53_scale_out" if _stage == "sgm-census"
        else "53_scale_out_sgm_default",
        title=lambda size, tile, label=_label: (
            f"Scale-out of sgm {label} ({size}² × 96): untiled vs tiles on 1 and 2 workers"),
        prepare=_sgm_prepare, command=_sgm_command(*_cost), quality=_sgm_quality,
        agreement=_sgm_agreement, phases=("match",), tile_size=1024))


# --- mapproject and dem --mapprojected: rendered line-scan views of analytic terrain ----
# (bench/_scale_linescan.py makes the scene)

def _mapproject_prepare(folder: Path, size: int) -> dict:
    from bench._scale_linescan import write_linescan_scene

    return write_linescan_scene(folder, size, views=1)


def _mapproject_command(inputs: dict, out: Path) -> list[str]:
    return [DEMTOOL, "mapproject", str(inputs["images"][0]), "--sensor",
            str(inputs["isds"][0]), "--dem", str(inputs["dem"]), "--gsd",
            str(inputs["gsd"]), "--out", str(out)]


def _mapproject_quality(inputs: dict, out: Path) -> dict[str, str]:
    from bench._scale_linescan import ortho_error

    rms, seen = ortho_error(out)
    return {"RMS vs truth (texture σ 0.1)": f"{rms:.4f}", "seen %": f"{100 * seen:.2f}"}


def _mapproject_agreement(inputs: dict, untiled: Path, tiled: Path) -> str:
    return raster_agreement(untiled, tiled, 1e-6, "")


register(ScaleCase(
    stage="mapproject", result="53_scale_out_mapproject",
    title=lambda size, tile: (
        f"Scale-out of mapproject, a line scanner ({size} lines × {size} samples onto a "
        "2 m DEM at 1 m): untiled vs tiles on 1 and 2 workers"),
    prepare=_mapproject_prepare, command=_mapproject_command,
    quality=_mapproject_quality, agreement=_mapproject_agreement,
    # setup: the sensor, the DEM under the footprint and the grid, mostly on one core
    # (the serial part that bounds the 2-worker efficiency; the imports come before it)
    phases=("setup", "project"), tile_size=1024,
    untiled_options=lambda tile: ("--tile-size", str(tile))))


def _dem_prepare(folder: Path, size: int) -> dict:
    from bench._scale_linescan import write_linescan_pair

    return write_linescan_pair(folder, size)


def _dem_command(inputs: dict, out: Path) -> list[str]:
    return [DEMTOOL, "dem", "--disparity", str(inputs["disparity"]), "--mapprojected",
            str(inputs["left"]), str(inputs["right"]), "--out", str(out)]


def _dem_quality(inputs: dict, out: Path) -> dict[str, str]:
    from bench._scale_linescan import dem_error

    rmse_gsd, completeness = dem_error(out, inputs["left"])
    return {"RMSE vs truth (GSD)": f"{rmse_gsd:.3f}",
            "completeness %": f"{100 * completeness:.2f}"}


def _dem_agreement(inputs: dict, untiled: Path, tiled: Path) -> str:
    return raster_agreement(untiled, tiled, 0.01, "m")


register(ScaleCase(
    stage="dem", result="53_scale_out_dem",
    title=lambda size, tile: (
        f"Scale-out of dem --mapprojected (two line-scan views {size}² px, B/H 0.44, "
        "their orthoimages and census disparity): untiled vs tiles on 1 and 2 workers"),
    prepare=_dem_prepare, command=_dem_command, quality=_dem_quality,
    agreement=_dem_agreement, phases=("coordinates", "triangulate", "grid"), tile_size=1024))


def sidecar(out: Path, name: str = "") -> dict:
    """The output's sidecar: ``<out>.json``, or ``out/<name>`` ({} when missing)."""
    path = Path(out) / name if name else Path(f"{out}.json")
    return json.loads(path.read_text()) if path.exists() else {}


import bench._scale_products  # noqa: E402,F401 - the refine, fuse and compare cases
