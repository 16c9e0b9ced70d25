"""The content of an ISIS control network (:mod:`demtool.io.controlnet`): network,
points and measures, whichever form (binary or PVL) they were read from.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from demtool.errors import InputError

#: ISIS pixel coordinates minus demtool's (CSM): the first pixel's centre is 1.0 vs 0.5
ISIS_PIXEL_OFFSET = 0.5
#: where ISIS (and plio) put the protobuf header: after a 64 KiB PVL label
HEADER_START_BYTE = 65536
_OBSOLETE = {"obsolete_Tie": "Free", "obsolete_Ground": "Fixed", "Tie": "Free",
             "Ground": "Fixed"}


@dataclass
class ControlMeasure:
    """One measure of a control point: where one image sees it.

    ``line``/``sample`` (and ``apriori_line``/``apriori_sample``) are demtool's pixel
    coordinates (first pixel centre at 0.5); ``line_residual``/``sample_residual`` and
    the sigmas are pixels, as ISIS writes them.  ``log`` keeps ISIS's log entries as
    ``(doubleDataType, doubleDataValue, boolDataType, boolDataValue)`` tuples (None
    where absent).  Optional fields absent from the file are None.
    """

    serial: str
    type: str = "Candidate"
    line: float | None = None
    sample: float | None = None
    line_residual: float | None = None
    sample_residual: float | None = None
    chooser_name: str | None = None
    datetime: str | None = None
    edit_lock: bool | None = None
    ignore: bool | None = None
    jigsaw_rejected: bool | None = None
    diameter: float | None = None
    apriori_line: float | None = None
    apriori_sample: float | None = None
    line_sigma: float | None = None
    sample_sigma: float | None = None
    log: list = field(default_factory=list)

    @property
    def ignored(self) -> bool:
        return bool(self.ignore)


@dataclass
class ControlPoint:
    """One control point: its type, a priori and adjusted body-fixed position and
    covariance (metres, m²; (3,) and (3, 3) arrays or None), and its measures.

    ``type`` is ``"Free"`` (image to image: a tie point), ``"Constrained"`` (its a priori
    position weighted by ``apriori_covariance``) or ``"Fixed"`` (held at its a priori
    position); ISIS's obsolete ``Tie``/``Ground`` read as Free/Fixed.
    """

    id: str
    type: str = "Free"
    measures: list[ControlMeasure] = field(default_factory=list)
    chooser_name: str | None = None
    datetime: str | None = None
    edit_lock: bool | None = None
    ignore: bool | None = None
    jigsaw_rejected: bool | None = None
    reference_index: int | None = None
    apriori_surface_point_source: str | None = None
    apriori_surface_point_source_file: str | None = None
    apriori_radius_source: str | None = None
    apriori_radius_source_file: str | None = None
    latitude_constrained: bool | None = None
    longitude_constrained: bool | None = None
    radius_constrained: bool | None = None
    apriori_xyz: np.ndarray | None = None
    apriori_covariance: np.ndarray | None = None
    adjusted_xyz: np.ndarray | None = None
    adjusted_covariance: np.ndarray | None = None
    log: list = field(default_factory=list)

    @property
    def ignored(self) -> bool:
        return bool(self.ignore)


@dataclass
class ControlNetwork:
    """An ISIS control network: header fields and points (file order)."""

    network_id: str
    target_name: str
    points: list[ControlPoint]
    created: str | None = None
    last_modified: str | None = None
    description: str | None = None
    user_name: str | None = None
    version: int = 5

    @property
    def measure_count(self) -> int:
        return sum(len(p.measures) for p in self.points)

    def serials(self) -> list[str]:
        """The serial numbers measured, in order of first appearance."""
        seen: dict[str, None] = {}
        for point in self.points:
            for measure in point.measures:
                seen.setdefault(measure.serial, None)
        return list(seen)


# -- covariance: ISIS stores the upper triangle (xx, xy, xz, yy, yz, zz), m² ----------------


def _covariance(values, source: str, what: str) -> np.ndarray | None:
    values = [float(v) for v in values]
    if not values:
        return None
    if len(values) != 6:
        raise InputError(f"{source}: {what} has {len(values)} values; ISIS stores 6 "
                         "(xx, xy, xz, yy, yz, zz)")
    xx, xy, xz, yy, yz, zz = values
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


def _triangle(matrix) -> list[float]:
    m = np.asarray(matrix, dtype=np.float64)
    return [float(m[0, 0]), float(m[0, 1]), float(m[0, 2]), float(m[1, 1]), float(m[1, 2]),
            float(m[2, 2])]


def _shift(value, offset: float):
    return None if value is None else float(value) + offset
