"""Ephemeris coverage: the times a model's position and pointing samples cover.

A line-scan or push-frame model interpolates its sensor position and attitude between
samples (Lagrange, Hermite, SLERP) and extrapolates beyond them without complaint, as
usgscsm does.  Between two samples much further apart than the rest (an ephemeris or
CK gap: e.g. a Mars Express HRSC ISD with a 111 s hole) or beyond the ends, the
"interpolated" orbit is invented.  This module keeps, per model, the time intervals the
samples cover, so that image lines exposed outside them are masked (their rays and
projections are NaN) and said so in one note, and ``demtool camera`` reports the
covered lines and the footprint of what is covered.  Only lines of the image
(``0 ≤ line ≤ lines``) are masked: points beyond the image ends are still extrapolated,
as callers such as mapproject's interpolation lattice expect.

Rules (times in seconds from the model's centre time):

- a series of samples covers ``[t_first − m, t_last + m]`` with the margin ``m`` one
  median sample spacing (a line a fraction of a sample beyond the last sample is
  interpolation, not invention); an attitude further, while continuing its end rotation
  rate stays within a tenth of a pixel (:func:`attitude_end_margins`: ALE's SLERP
  extrapolates at that rate, and a spacecraft turning steadily is extrapolated exactly);
- a step between two samples longer than :data:`GAP_FACTOR` median spacings is a gap:
  the times strictly inside it are not covered.  ALE thins smooth ephemerides (the
  shared real ISDs have steps up to 8× their median spacing: LRO NAC positions 3.04 s
  against 0.38 s, CTX pointing 0.24 against 0.12 s), so the factor sits above that;
  it was set on those files and has not been checked on a file with a real gap;
- a model covers the intersection of its position's and its pointing's intervals (and
  the body rotation's, when it has more than one sample).

Frame models expose once; their coverage is not checked here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: A step longer than this many median sample spacings is a gap (see module docstring).
GAP_FACTOR = 20.0


def sampled_intervals(times, *, gap_factor: float = GAP_FACTOR,
                      end_margins: tuple[float, float] | None = None
                      ) -> list[tuple[float, float]]:
    """Time intervals covered by samples at ``times`` (seconds, any order).

    One sample covers only itself; several cover their span widened by one median
    spacing at each end (or by ``end_margins``, seconds before the first and after the
    last sample, when larger), split at steps longer than ``gap_factor`` median spacings.
    """
    t = np.unique(np.asarray(times, dtype=np.float64).reshape(-1))
    if len(t) == 0:
        return []
    if len(t) == 1:
        return [(float(t[0]), float(t[0]))]
    steps = np.diff(t)
    spacing = float(np.median(steps))
    cuts = np.flatnonzero(steps > gap_factor * spacing)
    starts = np.concatenate([[0], cuts + 1])
    ends = np.concatenate([cuts, [len(t) - 1]])
    out = [(float(t[s] - spacing), float(t[e] + spacing))
           for s, e in zip(starts, ends, strict=True)]
    if end_margins is not None:
        lo, hi = out[0], out[-1]
        out[0] = (min(lo[0], float(t[0]) - end_margins[0]), lo[1])
        out[-1] = (out[-1][0], max(hi[1], float(t[-1]) + end_margins[1]))
    return out


#: An attitude is extrapolated beyond its samples only while the error of continuing its
#: end rotation rate (SLERP, as ALE's ``Orientations`` does) stays below this fraction of
#: a pixel's angle: ½ α t² ≤ fraction · IFOV, α the angular acceleration at that end.
ATTITUDE_EXTRAPOLATION_PX = 0.1


def attitude_end_margins(times, quaternions, ifov: float,
                         fraction: float = ATTITUDE_EXTRAPOLATION_PX) -> tuple[float, float]:
    """Seconds an attitude series may be extrapolated before its first and after its
    last sample (see :data:`ATTITUDE_EXTRAPOLATION_PX`), at most its own span; 0 with
    fewer than three samples (no acceleration to judge by).

    times : (n,) seconds; quaternions : (n, 4), any one component order; ifov : radians.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    q = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
    if len(t) < 3 or not (ifov > 0):
        return 0.0, 0.0
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    dots = np.abs(np.sum(q[1:] * q[:-1], axis=1)).clip(0.0, 1.0)
    rate = 2.0 * np.arccos(dots) / np.diff(t)  # rad/s between neighbours
    span = float(t[-1] - t[0])
    out = []
    for a, b, dt in ((rate[0], rate[1], t[2] - t[0]), (rate[-1], rate[-2], t[-1] - t[-3])):
        accel = abs(a - b) / (0.5 * dt)
        margin = span if accel == 0 else float(np.sqrt(2.0 * fraction * ifov / accel))
        out.append(min(margin, span))
    return out[0], out[1]


def intersect(first: list[tuple[float, float]], second: list[tuple[float, float]]
              ) -> list[tuple[float, float]]:
    """Intersection of two sorted lists of closed intervals."""
    out = []
    for a0, a1 in first:
        for b0, b1 in second:
            lo, hi = max(a0, b0), min(a1, b1)
            if lo <= hi:
                out.append((lo, hi))
    return sorted(out)


@dataclass
class Coverage:
    """Time intervals (seconds from the centre time) a model's samples cover.

    ``sources`` maps each series' name (``instrument_position``…) to its own intervals,
    for messages.
    """

    intervals: list[tuple[float, float]]
    sources: dict[str, list[tuple[float, float]]] = field(default_factory=dict)

    @classmethod
    def from_series(cls, series: dict[str, np.ndarray], *, gap_factor: float = GAP_FACTOR,
                    end_margins: dict[str, tuple[float, float]] | None = None) -> Coverage:
        """Coverage of named sample-time series (a one-sample series of a body
        rotation is constant and not counted); ``end_margins`` widens a series' ends
        (an attitude extrapolated by :func:`attitude_end_margins`)."""
        margins = end_margins or {}
        sources = {name: sampled_intervals(times, gap_factor=gap_factor,
                                           end_margins=margins.get(name))
                   for name, times in series.items() if np.size(times) > 1
                   or name != "body_rotation"}
        intervals: list[tuple[float, float]] | None = None
        for spans in sources.values():
            intervals = spans if intervals is None else intersect(intervals, spans)
        return cls(intervals or [], sources)

    def covers(self, times) -> np.ndarray:
        """Boolean array: which ``times`` lie in a covered interval."""
        times = np.asarray(times, dtype=np.float64)
        out = np.zeros(times.shape, dtype=bool)
        for lo, hi in self.intervals:
            out |= (times >= lo) & (times <= hi)
        return out


def covered_lines(model, coverage: Coverage | None = None) -> list[tuple[int, int]]:
    """Runs ``(first, last)`` of image rows (0-based, inclusive) whose exposure times the
    model's coverage holds; the whole image when the model has none."""
    coverage = coverage if coverage is not None else getattr(model, "coverage", None)
    if coverage is None:
        return [(0, int(model.lines) - 1)]
    rows = np.arange(int(model.lines))
    ok = coverage.covers(model.line_time(rows + 0.5))
    runs = []
    start = None
    for row, good in zip(rows, ok, strict=True):
        if good and start is None:
            start = int(row)
        if not good and start is not None:
            runs.append((start, int(row) - 1))
            start = None
    if start is not None:
        runs.append((start, int(rows[-1])))
    return runs


def coverage_note(model, runs: list[tuple[int, int]]) -> str | None:
    """One line saying which lines are masked and why, or None when all are covered."""
    lines = int(model.lines)
    covered = sum(b - a + 1 for a, b in runs)
    if covered == lines:
        return None
    where = ", ".join(f"{a}-{b}" for a, b in runs) or "none"
    spans = "; ".join(f"{name} {', '.join(f'{lo:+.3f}…{hi:+.3f}' for lo, hi in spans)} s"
                      for name, spans in model.coverage.sources.items())
    first, last = model.line_time(np.array([0.5, lines - 0.5]))
    return (f"{lines - covered} of {lines} lines ({100.0 * (lines - covered) / lines:.1f} %) "
            f"are exposed outside the sampled ephemeris or across a gap (lines at "
            f"{min(first, last):+.3f}…{max(first, last):+.3f} s; samples cover {spans}): "
            f"masked, covered lines {where}")


def attach_coverage(model, source: str, series: dict[str, np.ndarray],
                    end_margins: dict[str, tuple[float, float]] | None = None) -> None:
    """Give a line-scan or push-frame model the coverage of its sample times.

    Lines outside it are masked from then on; a note (kept in ``model.notes`` and
    logged) says which.  A model none of whose lines is covered is refused.

    Raises
    ------
    InputError
        No image line lies within the sampled ephemeris (one line naming ``source``).
    """
    import logging

    from demtool.errors import InputError

    coverage = Coverage.from_series(series, end_margins=end_margins)
    runs = covered_lines(model, coverage)
    model.coverage = coverage
    note = coverage_note(model, runs)
    if note is None:
        return
    timing = ""
    if getattr(model, "kind", "") == "pushframe":  # the line times are the framelets'
        timing = (" (the lines' times come from the framelet keys starting_ephemeris_time, "
                  "interframe_delay and exposure_duration: check those first)")
        note = note.replace(": masked", f"{timing}: masked")
    if not runs:
        raise InputError(f"{source}: no image line lies within the sampled ephemeris: "
                         f"{note.split(': masked')[0]}; demtool does not extrapolate the orbit "
                         "or the attitude")
    model.notes = list(getattr(model, "notes", [])) + [note]
    logging.getLogger("demtool.sensors").warning("%s: %s", source, note)
