"""Provenance: raster tags and the ``<output>.json`` sidecar every stage writes.

The sidecar is the manifest that makes a result reproducible: the stage, the demtool
version, the resolved parameters, each input with its SHA-256, wall time, peak memory
and the stage's summary figures.
"""

from __future__ import annotations

import functools
import hashlib
import os
import platform
import resource
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import demtool
from demtool import io as dio


def file_sha256(path: str | os.PathLike, chunk_size: int = 1 << 20) -> str | None:
    """SHA-256 of a file's content (hex), or None if it is not a readable file.

    A file is read once per process while it stays the same file with the same size and
    modification and change times (nanoseconds): a stage checks an input's hash against
    an orthoimage's tags and records it in its sidecar, and a sensor model that is an
    ISIS cube can be large.
    """
    p = Path(path)
    if not p.is_file():
        return None
    stat = p.stat()
    return _sha256_of(str(p.resolve()), stat.st_ino, stat.st_size, stat.st_mtime_ns,
                      stat.st_ctime_ns, chunk_size)


@functools.lru_cache(maxsize=256)
def _sha256_of(path: str, inode: int, size: int, mtime_ns: int, ctime_ns: int,
               chunk_size: int) -> str:
    """The hash of :func:`file_sha256`, cached by the file's identity and times."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(chunk_size):
            digest.update(block)
    return digest.hexdigest()


def peak_memory_mb() -> float:
    """Peak resident memory of this process so far, in MiB."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 1024.0 if sys.platform != "darwin" else peak / 2**20


class Provenance:
    """Collects what a stage run needs to describe its outputs.

    Create it when the stage starts (the clock starts then), pass ``tags()`` to every
    raster written, and call ``write_sidecar(output, summary)`` inside the stage's
    :func:`demtool.io.output_transaction`.

    Parameters
    ----------
    stage : str
        The subcommand name (``"sgm"``).
    params : mapping
        The resolved parameters (after config file and command line).
    inputs : sequence of path-like
        The input files (folders are listed by name, without a hash).
    """

    def __init__(self, stage: str, params: Mapping[str, Any],
                 inputs: Sequence[str | os.PathLike]) -> None:
        self.stage = stage
        self.params = {k: (str(v) if isinstance(v, Path) else v) for k, v in params.items()}
        self.inputs = [Path(p) for p in inputs]
        self.started = time.perf_counter()
        self.started_utc = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())

    def tags(self, **extra: Any) -> dict[str, Any]:
        """Raster tags: stage, version, parameters, input names, plus ``extra``."""
        tags: dict[str, Any] = {
            "demtool_stage": self.stage,
            "demtool_version": demtool.__version__,
            "demtool_params": self.params,
            "demtool_inputs": [p.name for p in self.inputs],
        }
        tags.update(extra)
        return tags

    def record(self, summary: Mapping[str, Any] | None = None,
               outputs: Sequence[str | os.PathLike] = ()) -> dict[str, Any]:
        """The manifest as a dict (what :meth:`write_sidecar` writes)."""
        return {
            "stage": self.stage,
            "demtool_version": demtool.__version__,
            "started_utc": self.started_utc,
            "command": " ".join(["demtool", *sys.argv[1:]]) if sys.argv else None,
            "parameters": self.params,
            "inputs": [{"path": str(p), "sha256": file_sha256(p)} for p in self.inputs],
            "outputs": [str(p) for p in outputs],
            "wall_time_s": round(time.perf_counter() - self.started, 3),
            "peak_memory_mb": round(peak_memory_mb(), 1),
            "python": platform.python_version(),
            "summary": dict(summary or {}),
        }

    def write_sidecar(self, output: str | os.PathLike, summary: Mapping[str, Any] | None = None,
                      outputs: Sequence[str | os.PathLike] = ()) -> Path:
        """Write ``<output>.json`` (atomically) and return its path."""
        sidecar = Path(f"{output}.json")
        dio.write_json(sidecar, self.record(summary, outputs or [output]))
        return sidecar


def recorded_inputs(output: str | os.PathLike) -> list[tuple[Path, str | None]]:
    """The inputs (path, SHA-256 or None) that ``<output>.json`` records, in order; empty
    when there is no sidecar or it is not one (a file made elsewhere is taken as given)."""
    import json

    try:
        record = json.loads(Path(f"{output}.json").read_text())
        return [(Path(str(entry["path"])), entry.get("sha256") or None)
                for entry in record.get("inputs", [])]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return []
