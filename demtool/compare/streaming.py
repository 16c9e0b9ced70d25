"""Exact statistics of values that arrive in pieces (a DEM difference read window by window).

* :class:`Moments` — count, mean, standard deviation (Chan, Golub & LeVeque 1983's
  pairwise update of the sum of squared deviations, stable when the mean is large), RMSE,
  min and max, merged window after window.
* :class:`OrderStatistic` — one order statistic (the k-th smallest value), found
  **exactly** in a few passes over the data with bounded memory: each pass histograms the
  values inside the interval known to hold the k-th value (4096 bins) and keeps the bin
  that holds it; once the interval holds at most ``gather_limit`` values, the next pass
  keeps those values and sorts them (the classic selection by bucketing, as in
  Munro & Paterson 1980's multi-pass selection).  Bins are half-open ``[e_i, e_{i+1})``
  with explicit edges, so the same comparisons decide membership in every pass and the
  result is the exact value, not an approximation.
* :class:`StreamStatistics` — everything :func:`demtool.compare.stats.difference_statistics`
  reports (count, mean, median, std, RMSE, NMAD, LE90, min, max), exact: the moments in
  one pass, the median and LE90 (the linearly interpolated 90th percentile of |x|, as
  ``np.percentile``) from their order statistics, NMAD = 1.4826 · median(|x − median|)
  (Höhle & Höhle 2009, eq. 4) from the order statistics of |x − median| once the median
  is known.

Memory: 4096 bin counts per order statistic and at most ``gather_limit`` values in its
last pass; passes: typically 2–3 for the median and LE90, then 2–3 for NMAD.

A pass over a piece is one compiled loop (:func:`_narrow`, :func:`_gather`; numba,
``nogil``, so pieces of different statistics go on different threads): the value (or its
``|x|``, ``|x − m|``) is counted below the interval or put in its bin, found from its
position and checked against the explicit edges, so it lands in the bin
``np.searchsorted(edges, x, side="right") − 1`` gives, without the temporaries.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from demtool.imaging.robust import NMAD_FACTOR

__all__ = ["BINS", "GATHER_LIMIT", "Moments", "OrderStatistic", "StreamStatistics"]

BINS = 4096  # histogram bins of one narrowing pass
GATHER_LIMIT = 1 << 18  # values kept (and sorted) in an order statistic's last pass

#: what an order statistic selects among (the piece's values as given, their absolute
#: values, or their absolute deviations from a centre): the ``mode`` of the kernels
AS_GIVEN, ABSOLUTE, DEVIATION = 0, 1, 2


@njit(cache=True, nogil=True)
def _value_of(x, mode, centre):
    if mode == 1:
        return abs(x)
    if mode == 2:
        return abs(x - centre)
    return x


@njit(cache=True, nogil=True)
def _narrow(values, mode, centre, low, high, edges, counts):
    """Count the values (``mode``: as given, ``|x|``, ``|x − centre|``) below ``low``
    (returned) and add those in ``[low, high)`` to ``counts``, bin ``i`` holding
    ``edges[i] <= x < edges[i + 1]`` (``edges`` strictly increasing, ``low`` and ``high``
    its ends)."""
    last = edges.size - 2  # the last bin
    scale = (last + 1) / (high - low)
    guess = np.isfinite(scale)
    below = 0
    for k in range(values.size):
        x = _value_of(values[k], mode, centre)
        if x < low:
            below += 1
        elif x < high:
            if guess:
                i = int(min(max((x - low) * scale, 0.0), float(last)))
                while i > 0 and edges[i] > x:
                    i -= 1
                while i < last and edges[i + 1] <= x:
                    i += 1
            else:  # pragma: no cover - an interval too narrow for its width in doubles
                i = np.searchsorted(edges, x, side="right") - 1
            counts[i] += 1
    return below


@njit(cache=True, nogil=True)
def _gather(values, mode, centre, low, high):
    """The count below ``low`` and the values in ``[low, high)`` (``mode`` as
    :func:`_narrow`), in the order given."""
    below = 0
    inside = 0
    for k in range(values.size):
        x = _value_of(values[k], mode, centre)
        if x < low:
            below += 1
        elif x < high:
            inside += 1
    kept = np.empty(inside)
    j = 0
    for k in range(values.size):
        x = _value_of(values[k], mode, centre)
        if low <= x < high:
            kept[j] = x
            j += 1
    return below, kept


class Moments:
    """Running count, mean, M2 (sum of squared deviations), sum of squares, min, max."""

    def __init__(self) -> None:
        self.count = 0
        self.total = 0.0
        self.squares = 0.0
        self.m2 = 0.0
        self.min = math.inf
        self.max = -math.inf

    def add(self, values: np.ndarray) -> None:
        """Merge a batch of finite float64 values (Chan et al. 1983, eq. 2.1b)."""
        self.merge(self.of(values))

    @staticmethod
    def of(values: np.ndarray) -> tuple[int, float, float, float, float, float] | None:
        """A batch's own count, sum, M2, sum of squares, min and max (None when empty),
        for :meth:`merge`: batches summarised on several threads and merged in their
        order give the numbers :meth:`add` in that order gives, to the bit."""
        n = int(values.size)
        if n == 0:
            return None
        total = float(values.sum())
        mean = total / n
        return (n, total, float(((values - mean) ** 2).sum()),
                float((values * values).sum()), float(values.min()), float(values.max()))

    def merge(self, batch: tuple[int, float, float, float, float, float] | None) -> None:
        """Merge a batch summarised by :meth:`of`."""
        if batch is None:
            return
        n, total, m2, squares, low, high = batch
        if self.count:
            delta = total / n - self.total / self.count
            self.m2 += m2 + delta * delta * self.count * n / (self.count + n)
        else:
            self.m2 = m2
        self.count += n
        self.total += total
        self.squares += squares
        self.min = min(self.min, low)
        self.max = max(self.max, high)

    def summary(self) -> dict[str, float]:
        """``mean``, ``std`` (population), ``rmse``, ``min``, ``max`` (NaN when empty)."""
        if not self.count:
            return {k: float("nan") for k in ("mean", "std", "rmse", "min", "max")}
        return {"mean": self.total / self.count,
                "std": math.sqrt(max(self.m2, 0.0) / self.count),
                "rmse": math.sqrt(self.squares / self.count),
                "min": self.min, "max": self.max}


class OrderStatistic:
    """The ``rank``-th smallest (0-based) of ``count`` values in ``[low, high]``, exactly.

    Feed every value of the data set to :meth:`add` (in any pieces), call
    :meth:`end_pass`, and repeat while :attr:`done` is False.
    """

    def __init__(self, rank: int, count: int, low: float, high: float, *,
                 bins: int = BINS, gather_limit: int = GATHER_LIMIT) -> None:
        if not 0 <= rank < count:
            raise ValueError(f"rank {rank} outside 0..{count - 1}")
        self.rank, self.bins, self.gather_limit = int(rank), int(bins), int(gather_limit)
        self.low = float(low)
        self.high = float(np.nextafter(high, np.inf))  # half-open [low, high)
        self.inside = int(count)  # values in [low, high)
        self.below = 0  # values < low
        self.value: float | None = None
        self.passes = 0
        self._start_pass()

    @property
    def done(self) -> bool:
        return self.value is not None

    def _start_pass(self) -> None:
        if self.value is not None:
            return
        if self.high <= np.nextafter(self.low, np.inf):  # one representable value left
            self.value = self.low
            return
        self._gather = self.inside <= self.gather_limit
        self._kept: list[np.ndarray] = []
        edges = np.unique(np.linspace(self.low, self.high, self.bins + 1))
        if edges.size < 3:  # a few ulps wide: split off the lowest value
            edges = np.array([self.low, np.nextafter(self.low, np.inf), self.high])
        self._edges = edges
        self._counts = np.zeros(edges.size - 1, dtype=np.int64)
        self._below = 0

    def add(self, values: np.ndarray, mode: int = AS_GIVEN, centre: float = 0.0) -> None:
        """One piece of this pass's values (float64, finite): the values as given, or
        (``mode``) their absolute values, or their absolute deviations from ``centre``."""
        if self.value is not None or values.size == 0:
            return
        values = np.ascontiguousarray(values, dtype=np.float64).ravel()
        if self._gather:
            below, kept = _gather(values, mode, float(centre), self.low, self.high)
            self._kept.append(kept)
        else:
            below = _narrow(values, mode, float(centre), self.low, self.high, self._edges,
                            self._counts)
        self._below += int(below)

    def end_pass(self) -> None:
        """Narrow the interval (or pick the value from the gathered ones)."""
        if self.value is not None:
            return
        self.passes += 1
        self.below = self._below
        offset = self.rank - self.below
        if self._gather:
            kept = np.concatenate(self._kept) if self._kept else np.empty(0)
            if not 0 <= offset < kept.size:  # pragma: no cover - data changed between passes
                raise RuntimeError("the values changed between two passes")
            self.value = float(np.partition(kept, offset)[offset])
            return
        cumulative = np.cumsum(self._counts)
        k = int(np.searchsorted(cumulative, offset, side="right"))
        if k >= self._counts.size:  # pragma: no cover - data changed between passes
            raise RuntimeError("the values changed between two passes")
        self.below += int(cumulative[k - 1]) if k else 0
        self.low, self.high = float(self._edges[k]), float(self._edges[k + 1])
        self.inside = int(self._counts[k])
        self._start_pass()


def _ranks(count: int, fraction: float) -> tuple[int, int, float]:
    """The two order statistics and the weight of ``np.percentile``'s linear method."""
    position = fraction * (count - 1)
    lower = int(math.floor(position))
    return lower, min(lower + 1, count - 1), position - lower


def _lerp(a: float, b: float, t: float) -> float:
    """``np.percentile``'s linear interpolation (numpy's ``_lerp``, exact at t = 0, 1)."""
    diff = b - a
    return b - diff * (1 - t) if t >= 0.5 else a + diff * t


class StreamStatistics:
    """:func:`demtool.compare.stats.difference_statistics` of values seen in pieces.

    Pass 1: :meth:`add` every finite value, then :meth:`end_pass`; while :attr:`done` is
    False, feed the same values again (:meth:`add`) and call :meth:`end_pass`.
    """

    def __init__(self, *, bins: int = BINS, gather_limit: int = GATHER_LIMIT) -> None:
        self.moments = Moments()
        self.bins, self.gather_limit = bins, gather_limit
        self.passes = 0
        self._order: dict[str, list[OrderStatistic]] = {}
        self._median: float | None = None

    @property
    def done(self) -> bool:
        if self.passes == 0:
            return False
        if self.moments.count == 0:
            return True
        return "deviation" in self._order and all(
            s.done for group in self._order.values() for s in group)

    def _select(self, ranks: tuple[int, ...], low: float, high: float) -> list[OrderStatistic]:
        return [OrderStatistic(r, self.moments.count, low, high, bins=self.bins,
                               gather_limit=self.gather_limit) for r in ranks]

    def add(self, values: np.ndarray) -> None:
        """One piece of the finite values (float64, any shape)."""
        values = np.asarray(values, dtype=np.float64).ravel()
        if self.passes == 0:
            self.moments.add(values)
            return
        self.add_again(values)

    def add_moments(self, batch: tuple[int, float, float, float, float, float] | None
                    ) -> None:
        """Pass 1's :meth:`add` of a piece summarised by :meth:`Moments.of` (on
        another thread, say); merged in the pieces' order, the same numbers."""
        if self.passes:
            raise RuntimeError("moments are added in the first pass only")
        self.moments.merge(batch)

    def add_again(self, values: np.ndarray) -> None:
        """A further pass's :meth:`add` (the order statistics): the pieces may come in
        any order and cut anyhow (counts, and the k-th of the values kept), as long as
        each pass sees every value once."""
        values = np.ascontiguousarray(values, dtype=np.float64).ravel()
        for name, group in self._order.items():
            mode = {"median": AS_GIVEN, "abs": ABSOLUTE, "deviation": DEVIATION}[name]
            centre = self._median if name == "deviation" else 0.0
            for statistic in group:
                statistic.add(values, mode, centre)

    def end_pass(self) -> None:
        self.passes += 1
        for group in self._order.values():
            for statistic in group:
                statistic.end_pass()
        n, m = self.moments.count, self.moments
        if not n:
            return
        if not self._order:
            middle = ((n - 1) // 2, n // 2)
            self._order["median"] = self._select(tuple(sorted(set(middle))), m.min, m.max)
            lower, upper, _ = _ranks(n, 0.9)
            largest = max(abs(m.min), abs(m.max))
            smallest = 0.0 if m.min <= 0.0 <= m.max else min(abs(m.min), abs(m.max))
            self._order["abs"] = self._select(tuple(sorted({lower, upper})), smallest, largest)
        if "deviation" not in self._order and all(s.done for s in self._order["median"]):
            self._median = self.median
            middle = tuple(sorted({(n - 1) // 2, n // 2}))
            reach = max(self._median - m.min, m.max - self._median)
            self._order["deviation"] = self._select(middle, 0.0, reach)

    def _value(self, name: str, rank: int) -> float:
        return next(s.value for s in self._order[name] if s.rank == rank)

    @property
    def median(self) -> float:
        n = self.moments.count
        a, b = self._value("median", (n - 1) // 2), self._value("median", n // 2)
        return a if a == b else float(np.mean([a, b]))

    def result(self) -> dict[str, Any]:
        """The keys of :func:`difference_statistics` (NaN when no value)."""
        n = self.moments.count
        if n == 0:
            return {"count": 0, **{k: float("nan") for k in
                                   ("mean", "median", "std", "rmse", "nmad", "le90", "min",
                                    "max")}}
        lower, upper, t = _ranks(n, 0.9)
        deviation = self._value("deviation", (n - 1) // 2), self._value("deviation", n // 2)
        mad = deviation[0] if deviation[0] == deviation[1] else float(np.mean(deviation))
        summary = self.moments.summary()
        return {"count": int(n), "mean": summary["mean"], "median": self.median,
                "std": summary["std"], "rmse": summary["rmse"],
                "nmad": float(NMAD_FACTOR * mad),
                "le90": float(_lerp(self._value("abs", lower), self._value("abs", upper), t)),
                "min": summary["min"], "max": summary["max"]}
