"""From a control network and the images' sensor models to a :class:`NetworkProblem`.

Serial numbers: ISIS names each image in a network by its cube's serial number
(``SpacecraftName/InstrumentId/SpacecraftClockCount`` for most missions, e.g. MRO CTX
``MRO/CTX/0884541979:200``; ISIS ``SerialNumber``, plio ``generate_serial_number``,
which knoten uses to key its sensors).  An ISD or a model does not carry it, so the
serials are matched to the models

1. by an explicit list (``serials``: one serial per model, same order), else
2. for ISIS cubes, by the clock count in the cube's label (``SpacecraftClockCount``,
   ``SpacecraftClockStartCount``), which is the serial's last part for most missions
   (ISIS ``SerialNumberKeywords`` translations), else
3. by the spacecraft clock in the serials: a clock count is a time since the mission's
   clock epoch, so the differences between the images' clock counts equal the
   differences between their start times (ephemeris seconds), within the clock's drift
   (1 s plus 1e-6 of the interval; MRO's drifts 13 s in 132 Ms).  Each mission (the
   serial's part before the clock: ``MRO/CTX``) has its own epoch: the match is, per
   mission, the one-to-one assignment under one epoch offset, else
4. by name: a serial that contains a model's image name, and last, a single serial left
   with a single model left.

The pixel coordinates are checked against each image (a measure outside its image is
an error: the wrong image, or a network of other images).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from demtool.errors import InputError

_CLOCK = re.compile(r"(?<![\d.])(\d{5,})(?:[:.](\d+))?")


def serial_clock(serial: str) -> float | None:
    """The spacecraft clock count (whole seconds) in a serial number, or None."""
    for part in serial.split("/")[1:]:
        match = _CLOCK.fullmatch(part.strip())
        if match:
            return float(match.group(1))
    return None


def start_time(model) -> float | None:
    """Ephemeris seconds (TDB past J2000) of a model's first exposure, or None."""
    centre = getattr(model, "center_time", None)
    if centre is None:
        centre = getattr(model, "time", None)
    if centre is None:
        return None
    if hasattr(model, "line_time"):
        return float(centre) + float(model.line_time(0.0))
    return float(centre)


def label_clock(path) -> str | None:
    """The clock count in an ISIS cube's label (``SpacecraftClockCount``,
    ``SpacecraftClockStartCount``), or None."""
    from pathlib import Path

    from demtool.sensors.isis_label import read_label

    try:
        label, _ = read_label(Path(path))
        instrument = label["IsisCube"]["Instrument"]
    except Exception:  # not a cube, or no Instrument group: no clock to match by
        return None
    for key in ("SpacecraftClockCount", "SpacecraftClockStartCount",
                "SpacecraftClockPrerollCount"):
        if key in instrument:
            return str(instrument[key]).strip().strip('"')
    return None


def _mission(serial: str) -> str:
    parts = serial.split("/")
    for k, part in enumerate(parts[1:], start=1):
        if _CLOCK.fullmatch(part.strip()):
            return "/".join(parts[:k])
    return serial


def _match_by_clock(serials, models, indices=None) -> dict[str, int] | None:
    indices = list(range(len(models))) if indices is None else list(indices)
    clocks = [serial_clock(s) for s in serials]
    times = [start_time(models[i]) for i in indices]
    if any(c is None for c in clocks) or any(t is None for t in times) or not serials:
        return None
    best = None
    for c in clocks:
        for t in times:
            offset = c - t
            pairs = {}
            for s, clock in zip(serials, clocks, strict=True):
                errors = [abs(clock - time - offset) for time in times]
                i = int(np.argmin(errors))
                tolerance = 1.0 + 1e-6 * abs(clock - c) + 0.5  # drift, whole-second clock
                if errors[i] <= tolerance:
                    pairs[s] = i
            if len(set(pairs.values())) == len(pairs) and (best is None or
                                                          len(pairs) > len(best)):
                best = pairs
    if best is None or not best:
        return None
    if len(serials) > 1 and len(best) < 2 or len(serials) == 1 and len(indices) > 1:
        return None  # one image alone fixes no epoch offset: no evidence
    return {s: indices[i] for s, i in best.items()}


def match_serials(serials: Sequence[str], models: Sequence, names: Sequence[str], *,
                  explicit: Sequence[str] | None = None, source: str = "network",
                  label_clocks: Sequence[str | None] | None = None) -> dict[str, int]:
    """Map each serial number to the index of its model (module docstring); serials of
    images not given are left out.  ``label_clocks``: the clock count of each model's
    cube label (None for other models).

    Raises
    ------
    InputError
        No serial matches an image, or the explicit list has the wrong length.
    """
    if explicit is not None:
        if len(explicit) != len(models):
            raise InputError(f"--serials: {len(explicit)} serial number(s) for "
                             f"{len(models)} sensor models; give one per model, same order")
        mapping = {s: i for i, s in enumerate(explicit) if s in set(serials)}
    else:
        mapping = {}
        for i, clock in enumerate(label_clocks or []):  # cubes: the label's clock count
            hits = [s for s in serials if clock and s.split("/")[-1].strip() == clock]
            if len(hits) == 1:
                mapping[hits[0]] = i
        groups: dict[str, list[str]] = {}
        for s in serials:
            if s not in mapping:
                groups.setdefault(_mission(s), []).append(s)
        for group in groups.values():  # one clock epoch per mission
            free = [i for i in range(len(models)) if i not in mapping.values()]
            found = _match_by_clock(group, list(models), free) if free else None
            for s, i in (found or {}).items():
                if i not in mapping.values():
                    mapping[s] = i
        for s in serials:
            if s not in mapping:
                hits = [i for i, n in enumerate(names) if n and n in s]
                if len(hits) == 1 and hits[0] not in mapping.values():
                    mapping[s] = hits[0]
        left = [s for s in serials if s not in mapping]
        free = [i for i in range(len(models)) if i not in mapping.values()]
        if mapping and len(left) == 1 and len(free) == 1:
            mapping[left[0]] = free[0]  # the one serial left is the one image left
    if not mapping:
        raise InputError(f"{source}: none of its {len(serials)} serial numbers "
                         f"({', '.join(list(serials)[:3])}{' ...' if len(serials) > 3 else ''}"
                         f") matches an image of {', '.join(names)}; give the serials "
                         "with --serials (one per sensor model, same order)")
    return mapping


def build_problem(network, models: Sequence, names: Sequence[str], mapping: dict[str, int],
                  *, solve: np.ndarray, sigmas: np.ndarray, pixel_sigma: float,
                  source: str = "network"):
    """The :class:`demtool.bundle.network.NetworkProblem` of a network.

    Ignored points and measures, measures of serials not in ``mapping`` and free points
    with fewer than two measures are left out.  Free points start triangulated from
    the prior models (the least-squares intersection of their rays, as knoten's
    ``compute_apriori_ground_points``); constrained and fixed points at their a priori
    positions.

    Returns
    -------
    problem : NetworkProblem
    point_index : list of int
        The network index of each problem point.
    measure_index : list of (int, int)
        (network point index, measure index in the point) of each observation.
    """
    from demtool.bundle.network import NetworkProblem
    from demtool.bundle.priors import Observations, triangulate

    image, point, line, sample = [], [], [], []
    kinds, priors, apriori, point_index, measure_index = [], [], [], [], []
    for p_index, p in enumerate(network.points):
        if p.ignored:
            continue
        rows = []
        for m_index, m in enumerate(p.measures):
            if m.ignored or m.serial not in mapping or m.line is None or m.sample is None:
                continue
            i = mapping[m.serial]
            model = models[i]
            if not (0.0 <= m.line <= model.lines and 0.0 <= m.sample <= model.samples):
                raise InputError(f"{source}: point {p.id}: measure of {m.serial} at line "
                                 f"{m.line + 0.5:.2f}, sample {m.sample + 0.5:.2f} (ISIS) "
                                 f"lies outside its image {names[i]} ({model.samples} x "
                                 f"{model.lines} px)")
            rows.append((i, m.line, m.sample, m_index))
        kind = {"Free": 0, "Constrained": 1, "Fixed": 2}[p.type]
        if (kind == 0 and len(rows) < 2) or not rows:
            continue
        if kind > 0 and p.apriori_xyz is None:
            raise InputError(f"{source}: {p.type.lower()} point {p.id} has no a priori "
                             "position (AprioriX/Y/Z)")
        cov = p.apriori_covariance
        if kind == 1 and (cov is None or not np.all(np.linalg.eigvalsh(cov) > 0)):
            raise InputError(f"{source}: constrained point {p.id} has no positive a priori "
                             "covariance (aprioriCovar)")
        n = len(point_index)
        for i, ln, sm, m_index in rows:
            image.append(i)
            point.append(n)
            line.append(ln)
            sample.append(sm)
            measure_index.append((p_index, m_index))
        kinds.append(kind)
        priors.append(cov if kind == 1 else np.eye(3))
        apriori.append(p.apriori_xyz if p.apriori_xyz is not None else np.zeros(3))
        point_index.append(p_index)
    if not point_index:
        raise InputError(f"{source}: no point with measures in the images given")
    obs = Observations(np.array(image), np.array(point), np.array(line, dtype=np.float64),
                       np.array(sample, dtype=np.float64))
    kinds = np.array(kinds)
    points = np.array(apriori, dtype=np.float64)
    free = kinds == 0
    if np.any(free):
        triangulated, _ = triangulate(list(models), obs)
        points[free] = triangulated[free]
    problem = NetworkProblem(models=list(models), observations=obs, points=points,
                             point_kind=kinds, point_prior=np.array(priors),
                             apriori_points=np.array(apriori, dtype=np.float64),
                             solve=solve, sigmas=sigmas, pixel_sigma=pixel_sigma)
    return problem, point_index, measure_index

