"""Conformance: every real camera file of ``../shared/data/conformance`` (the test corpora of
ALE, ISIS and usgscsm) and ``../shared/data/sensors`` through demtool's one reader entry
point, :func:`demtool.sensors.read_sensor` (issue 41).

Per file: loaded or refused (the one-line reason), the model kind, the image size, the
fraction of a 33 × 33 grid of image rays that meets the body's ellipsoid, the largest
image → ground → image error on those rays (the target is ≤ 0.01 px; a push frame's point
is projected back into the framelet it came from, since overlapping framelets see the same
ground twice) and the footprint centre (planetocentric longitude and latitude of the mean
of the ground points).  A model that loads but does not close is the worst outcome (a
wrong geometry, silently): its verdict is ``WRONG``.  A reader that crashes (any error
other than demtool's one-line :class:`~demtool.errors.InputError`) is ``CRASH``.

Files are grouped by mission and instrument, taken from the corpus README's tables
(``conformance/README.md``) where it lists the file, otherwise from the file itself (an
ISD's ``name_platform`` / ``name_sensor``, a cube label's ``SpacecraftName`` /
``InstrumentId``).

    python bench/conformance.py                       # both folders; records the table
    python bench/conformance.py 'PATH/*.json' DIR     # a subset (files, folders, globs)
    python bench/conformance.py --record PATHS        # a subset, recorded anyway

Reads ``../shared/data``; prints a message and exits 0 when it is absent.  The table is
recorded in ``bench/results/70_conformance.json`` (``bench/validation_page.py`` puts it on
``docs/validation.md``) when the default folders are run, or with ``--record``.
"""

from __future__ import annotations

import argparse
import glob
import json
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data"
FOLDERS = (SHARED / "conformance", SHARED / "sensors")
SUFFIXES = (".json", ".isd", ".cub")
GRID = 33
#: round-trip target (pixels) of issue 41.
TOLERANCE_PX = 0.01


@dataclass
class Result:
    """One file's outcome (see the module docstring)."""

    path: Path
    group: str
    status: str  # "ok", "refused", "WRONG", "CRASH", "no ground"
    reason: str = ""
    kind: str = ""
    size: str = ""
    hit_fraction: float = float("nan")
    round_trip_px: float = float("nan")
    centre: tuple[float, float] | None = None
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)


def collect(paths=None) -> list[Path]:
    """Camera files (``.json``, ``.isd``, ``.cub``) under the given files, folders or glob
    patterns (default: both shared folders), sorted, without repeats."""
    found: set[Path] = set()
    for item in (paths or [str(f) for f in FOLDERS if f.is_dir()]):
        matches = [Path(m) for m in glob.glob(str(item), recursive=True)] or [Path(item)]
        for match in matches:
            if match.is_dir():
                found.update(p for p in match.rglob("*") if p.is_file()
                             and p.suffix.lower() in SUFFIXES)
            elif match.is_file():
                found.add(match)
    return sorted(found, key=lambda p: str(p.resolve()))


def readme_groups(readme: Path = SHARED / "conformance" / "README.md") -> dict[str, str]:
    """``{file name: mission / instrument}`` from the corpus README's tables."""
    groups: dict[str, str] = {}
    if not readme.is_file():
        return groups
    for line in readme.read_text(encoding="utf-8").splitlines():
        m = re.match(r"\|\s*`([^`]+)`\s*\|\s*([^|]+?)\s*\|", line)
        if m:
            groups[Path(m.group(1)).name] = m.group(2)
    return groups


def file_group(path: Path, groups: dict[str, str]) -> str:
    """Mission / instrument of a file: the README's, else from its own content."""
    if path.name in groups:
        return groups[path.name]
    try:
        with path.open("rb") as handle:
            head = handle.read(65536).decode("latin-1")
    except OSError:
        return "?"
    if head.lstrip().startswith("{"):
        try:
            isd = json.loads(path.read_text(encoding="utf-8"))
        except (ValueError, OSError):
            return "?"
        parts = [str(isd.get(k)) for k in ("name_platform", "name_sensor") if isd.get(k)]
        return " ".join(parts) or f"{path.parent.name} (ISD)"
    parts = [m.group(1).strip('"') for key in ("SpacecraftName", "InstrumentId")
             if (m := re.search(rf"^\s*{key}\s*=\s*(.+?)\s*$", head, re.M))]
    return " ".join(parts) or f"{path.parent.name} (cube)"


def _grid(model, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n × n`` image points from edge to edge (a 1-pixel image: across that pixel)."""
    eps = 1e-6  # the far edge belongs to no pixel (a push frame's next framelet)
    return np.meshgrid(np.linspace(0.0, float(model.lines) - eps, n),
                       np.linspace(0.0, float(model.samples) - eps, n), indexing="ij")


def measure(model, n: int = GRID) -> tuple[float, float, tuple[float, float] | None]:
    """Fraction of an ``n × n`` ray grid meeting the body, the largest round-trip error
    (px) on those rays, and the footprint centre (lon, lat in degrees, planetocentric).

    ``ground_to_image`` is called as every stage calls it (no framelet hint).  Where it
    returns another pixel than the one the ray came from (overlapping push-frame
    framelets, a scan mirror seeing the same ground twice), that pixel's own ray must
    land back on the same ground within 0.01 GSD (the local ground size of one pixel);
    then the error counted is that distance in GSD (pixels of ground).
    """
    from demtool.sensors import ray_ellipsoid_intersection
    from demtool.sensors.body_view import reference_height

    lines, samples = _grid(model, n)
    a, b = model.radii
    h = reference_height(model)  # a surface camera: the ground just below it
    with np.errstate(all="ignore"):
        ray = model.image_to_ray(lines, samples)
        ground, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, a, b, h,
                                                 return_hit=True)
        hit &= np.all(np.isfinite(ground), axis=-1)
        fraction = float(hit.mean())
        if not np.any(hit):  # a body smaller than the grid spacing: a grid over it
            lines, samples = _zoom_grid(model, n)
            if lines is None:
                return 0.0, float("nan"), None
            ray = model.image_to_ray(lines, samples)
            ground, hit = ray_ellipsoid_intersection(ray.origin, ray.direction, a, b, h,
                                                     return_hit=True)
            hit &= np.all(np.isfinite(ground), axis=-1)
            if not np.any(hit):
                return 0.0, float("nan"), None
        ln, sm, xyz = lines[hit], samples[hit], ground[hit]
        back = model.ground_to_image(xyz)
        err = np.hypot(back[0] - ln, back[1] - sm)
        err = np.where(np.isfinite(err), err, np.inf)
        far = err > TOLERANCE_PX
        if np.any(far):  # another pixel seeing the same ground?
            other = model.image_to_ground(back[0][far], back[1][far], h)
            step = model.image_to_ground(ln[far] + 1.0, sm[far], h)
            step2 = model.image_to_ground(ln[far], sm[far] + 1.0, h)
            gsd = np.maximum(np.linalg.norm(step - xyz[far], axis=-1),
                             np.linalg.norm(step2 - xyz[far], axis=-1))
            in_gsd = np.linalg.norm(other - xyz[far], axis=-1) / gsd
            err[far] = np.where(np.isfinite(in_gsd) & (in_gsd <= TOLERANCE_PX), in_gsd,
                                err[far])
    mean = xyz.mean(axis=0)
    lon = float(np.degrees(np.arctan2(mean[1], mean[0])))
    lat = float(np.degrees(np.arctan2(mean[2], np.hypot(mean[0], mean[1]))))
    return fraction, float(np.max(err)), (lon, lat)


def _zoom_grid(model, n: int):
    """An ``n × n`` grid over the part of the image where the body is, when it is smaller
    than the full grid's spacing: the bounding box of its ellipsoid's points facing the
    camera, projected; (None, None) when none lands in the image."""
    a, b = model.radii
    with np.errstate(all="ignore"):
        centre = np.asarray(model.image_to_ray(np.array([0.5 * model.lines]),
                                               np.array([0.5 * model.samples])).origin)[0]
        lon, lat = np.meshgrid(np.linspace(-np.pi, np.pi, 72), np.linspace(-1.5, 1.5, 36))
        pts = np.stack([a * np.cos(lat) * np.cos(lon), a * np.cos(lat) * np.sin(lon),
                        b * np.sin(lat)], axis=-1).reshape(-1, 3)
        pts = pts[np.sum(pts * (centre - pts), axis=-1) > 0]  # the side facing the camera
        if not len(pts):
            return None, None
        line, sample = model.ground_to_image(pts)
    inside = np.isfinite(line) & np.isfinite(sample) & (line >= 0) & (line <= model.lines) \
        & (sample >= 0) & (sample <= model.samples)
    if not np.any(inside):
        return None, None
    lo_l, hi_l = line[inside].min(), line[inside].max()
    lo_s, hi_s = sample[inside].min(), sample[inside].max()
    pad_l, pad_s = max(hi_l - lo_l, 1.0), max(hi_s - lo_s, 1.0)
    lines = np.linspace(max(lo_l - pad_l, 0.0), min(hi_l + pad_l, model.lines), n)
    samples = np.linspace(max(lo_s - pad_s, 0.0), min(hi_s + pad_s, model.samples), n)
    return np.meshgrid(lines, samples, indexing="ij")


def check_file(path: Path, group: str = "") -> Result:
    """Read one file through :func:`demtool.sensors.read_sensor` and measure it."""
    from demtool.errors import InputError
    from demtool.sensors import read_sensor

    start = time.perf_counter()
    result = Result(path=path, group=group or file_group(path, readme_groups()), status="")
    try:
        model = read_sensor(path, require_surface=False)
    except InputError as exc:
        text = str(exc)
        prefix = f"{path}: "
        result.status, result.reason = "refused", text[len(prefix):] if text.startswith(
            prefix) else text
        result.seconds = time.perf_counter() - start
        return result
    except Exception as exc:  # noqa: BLE001 - a crash is what this benchmark reports
        result.status, result.reason = "CRASH", f"{type(exc).__name__}: {exc}"
        result.seconds = time.perf_counter() - start
        return result
    result.kind = str(getattr(model, "kind", "") or type(model).__name__)
    result.size = f"{int(model.samples)}×{int(model.lines)}"
    result.notes = [str(n) for n in (getattr(model, "notes", None) or [])]
    if getattr(model, "radii", None) is None or not model.lines or not model.samples:
        result.status, result.reason = "ok", "no body or image size: not measured"
        result.seconds = time.perf_counter() - start
        return result
    try:
        result.hit_fraction, result.round_trip_px, result.centre = measure(model)
    except Exception as exc:  # noqa: BLE001
        result.status, result.reason = "CRASH", f"measuring: {type(exc).__name__}: {exc}"
        result.seconds = time.perf_counter() - start
        return result
    if result.centre is None:
        result.status = "no ground"
        result.reason = "loads; no ray of the image meets the body"
    elif result.hit_fraction == 0 and result.round_trip_px <= TOLERANCE_PX:
        result.status = "ok"
        result.notes.append("the body is smaller than the grid's spacing: measured on a "
                            f"{GRID}×{GRID} grid over it")
    elif result.round_trip_px <= TOLERANCE_PX:
        result.status = "ok"
    else:
        result.status = "WRONG"
        result.reason = f"round trip {result.round_trip_px:.3g} px > {TOLERANCE_PX} px"
    result.seconds = time.perf_counter() - start
    return result


def run(paths=None) -> list[Result]:
    """:func:`check_file` on every file :func:`collect` finds."""
    groups = readme_groups()
    return [check_file(p, file_group(p, groups)) for p in collect(paths)]


def _short(path: Path) -> str:
    for folder in FOLDERS:
        try:
            rel = path.resolve().relative_to(folder.resolve())
        except ValueError:
            continue
        parts = rel.parts
        return f"{folder.name}/{parts[0]}/…/{path.name}" if len(parts) > 2 else \
            f"{folder.name}/{rel}"
    return str(path)


def rows(results: list[Result]) -> list[list[str]]:
    """Table rows, grouped by mission / instrument."""
    out = []
    for r in sorted(results, key=lambda r: (r.group.lower(), str(r.path))):
        hit = "—" if np.isnan(r.hit_fraction) else f"{100 * r.hit_fraction:.0f} %"
        rt = "—" if np.isnan(r.round_trip_px) else f"{r.round_trip_px:.1e}"
        centre = "—" if r.centre is None else f"{r.centre[0]:.2f}, {r.centre[1]:.2f}"
        named = name_target(r.path.name)
        if named is not None and r.centre is not None:
            centre += (f" (name: {named[1]:+.0f}, {named[0]:+.0f}; "
                       f"{angle_deg(named, r.centre):.1f}° off)")
        why = r.reason if r.status != "ok" else "; ".join(r.notes)
        out.append([r.group, f"`{r.path.name}`", r.status, r.kind or "—", r.size or "—", hit,
                    rt, centre, why[:240]])
    return out


def name_target(name: str) -> tuple[float, float] | None:
    """(lat, lon °E) a PDS product name states for its image centre (MRO's
    ``…_22N022W``, ``…_00N096W``), or None."""
    m = re.search(r"_(\d{2})([NS])(\d{3})([EW])(?:[._]|$)", name)
    if m is None:
        return None
    lat = float(m.group(1)) * (1 if m.group(2) == "N" else -1)
    lon = float(m.group(3)) * (1 if m.group(4) == "E" else -1)
    return lat, lon


def angle_deg(named: tuple[float, float], centre: tuple[float, float]) -> float:
    """Great-circle angle (degrees) between a named (lat, lon) and a (lon, lat) centre."""
    lat1, lon1 = np.radians(named)
    lon2, lat2 = np.radians(centre)
    c = np.sin(lat1) * np.sin(lat2) + np.cos(lat1) * np.cos(lat2) * np.cos(lon1 - lon2)
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


COLUMNS = ["mission / instrument", "file", "verdict", "model", "size (s×l)",
           "rays on body", "round trip px", "centre lon, lat ° (the name's)",
           "reason / notes"]


def summary(results: list[Result]) -> str:
    counts: dict[str, int] = {}
    for r in results:
        counts[r.status] = counts.get(r.status, 0) + 1
    return ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())) + f" (of {len(results)})"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="*", help="files, folders or glob patterns "
                        "(default: ../shared/data/conformance and ../shared/data/sensors)")
    parser.add_argument("--record", action="store_true",
                        help="record the table even for a subset")
    args = parser.parse_args(argv)
    if not args.paths and not any(f.is_dir() for f in FOLDERS):
        print(f"skipped: {SHARED.resolve()} is absent (conformance corpus not available)")
        return 0
    results = run(args.paths or None)
    if not results:
        print("no camera files (.json, .isd, .cub) found")
        return 0
    table = rows(results)
    group = None
    for row in table:
        if row[0] != group:
            group = row[0]
            print(f"-- {group}")
        print(f"   {row[1][1:-1][:44]:44s} {row[2]:9s} {row[3]:9s} {row[4]:>11s} "
              f"{row[5]:>5s} {row[6]:>8s} {row[7]:>16s}  {row[8][:110]}")
    print(summary(results))
    if not args.paths or args.record:
        sys.path.insert(0, str(ROOT))
        from bench.validation_page import write_result

        write_result(
            "70_conformance", title="Conformance: the reference tools' camera files",
            section="Sensor models", order=70,
            command="python bench/conformance.py" + (" " + " ".join(args.paths)
                                                     if args.paths else ""),
            date=time.strftime("%Y-%m-%d"), machine="2-core shared VM (CPU)",
            columns=COLUMNS, rows=table,
            notes=("Every file of `../shared/data/conformance` (ALE, ISIS and usgscsm test "
                   "corpora) and `../shared/data/sensors` through `read_sensor`. Verdicts: "
                   "`ok` loads and closes image → ground → image within "
                   f"{TOLERANCE_PX} px on every ray of a {GRID}×{GRID} grid that meets the "
                   "body; `no ground` loads but no ray meets the body; `refused` one-line "
                   "reason; `WRONG` loads but does not close; `CRASH` an unexpected error. "
                   f"Summary: {summary(results)}."))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
