"""Parameters of ``demtool camera`` (core: :mod:`demtool.camera.info`).

The command's options are generated from these fields; the footprint sampling default
is read from :func:`demtool.camera.info.footprint`.
"""

from __future__ import annotations

from dataclasses import dataclass

from demtool.camera.info import footprint
from demtool.parameters import Parameters, core_default, parameter


@dataclass(frozen=True)
class CameraParams(Parameters):
    """Every option of ``demtool camera`` except its files and ``--json``."""

    body: str | None = parameter(
        None, "Body of the models, by name or NAIF id (Moon, 499): needed by .tsai "
        "pinholes, which carry no radii; names the body of the others.", metavar="BODY")
    points_per_edge: int = parameter(
        core_default(footprint, "points_per_edge"), "Footprint samples along each image "
        "edge.", minimum=2)

    def check(self) -> None:
        super().check()
        if self.body is not None and not str(self.body).strip():
            self.fail("body", "must name a body (e.g. Moon, Mars, 301)")
