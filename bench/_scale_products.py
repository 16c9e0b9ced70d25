"""The refine, fuse and compare cases of bench/scale_out.py (registered in
bench/_scale_cases.py's registry; how a case works: that module's docstring).

Inputs, all synthetic with known truth, made once per run at ``--size``² cells of 1 m:

* a fractal relief (power spectrum ∝ k^-3, 8 m RMS) with bowl craters, the truth;
* **refine**: the truth rendered by demtool's own lunar-Lambert model
  (:func:`demtool.refine.shading.render_dem`, sun azimuth 120°, elevation 45°, nadir
  view) times a ±10 % low-frequency albedo, with 1 % noise; the coarse DEM is the truth
  smoothed by a Gaussian of σ = 6 cells plus 0.2 m noise (bench/refine_speed.py's
  recipe); ``refine --iterations 20`` (the default 60 triples the time, not the shape of
  the table); quality: RMSE against the truth before and after, metres; agreement: the
  RMSE of tiled − untiled in GSD (issue 15's tolerance < 0.02 GSD);
* **fuse**: three DEMs of the truth with 0.3 m noise, offsets of 0, +0.5 and +1.0 m, a
  left strip of 5, 10 and 15 % of the width missing and 1 % of the cells in holes up to
  13 cells wide; ``fuse`` with its defaults (huber, nuth-kaab); quality: RMSE of the fused
  DEM against the truth shifted by the first DEM's offset, completeness; agreement: the
  tiled output against the untiled (the tiles' margin makes them identical);
* **compare**: the truth shifted by (−1.3, +0.7) cells and 2.0 m, with 0.05 m noise,
  compared with the truth; quality: the recovered shift and the NMAD.  compare has no
  worker processes (its ``--tile-size`` streams windows through one process to bound
  memory), so only its untiled row is measured;
* **compare-windowed** (compare's windowed path, the one bench/nac_full.py's route
  takes): the truth (``--size``² cells of 2 m, on an equirectangular map of the Moon)
  NaN outside the DEM's footprint, and a DEM of 1 m cells on another equirectangular
  map (another central meridian and true-scale latitude: PROJ transforms every cell),
  2·size × size cells over the truth's middle half, sampled (cubic) from the truth
  shifted by (−1.3, +0.7) truth cells and 2 m, with 0.05 m noise; ``compare
  --tile-size`` 1024 (half the grid's side below 2048); one row, its phases.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench._scale_cases import DEMTOOL, ScaleCase, raster_agreement, register

SUN_AZIMUTH, SUN_ELEVATION = 120.0, 45.0
REFINE_ITERATIONS = 20
FUSE_OFFSETS = (0.0, 0.5, 1.0)  # metres added to DEM i
COMPARE_SHIFT = (-1.3, 0.7, 2.0)  # dx, dy cells (x right, y down) and dz metres of the DEM
#: Default tile of refine and fuse: each tile recomputes its margin (refine 113 px, fuse
#: 66 cells with the defaults), 11 % and 7 % more pixels in 2048-px tiles of a 4096² grid
#: (four tiles, two per worker), 49 % and 28 % in 1024-px interior tiles.
TILE = 2048


def truth_surface(size: int, seed: int = 1) -> np.ndarray:
    """A ``size``² fractal relief with craters, metres (float64, 1 m cells)."""
    rng = np.random.default_rng(seed)
    k2 = np.fft.fftfreq(size)[:, None] ** 2 + np.fft.rfftfreq(size)[None, :] ** 2
    k2[0, 0] = 1.0
    spectrum = (rng.normal(size=k2.shape) + 1j * rng.normal(size=k2.shape)) * k2 ** -0.75
    spectrum[0, 0] = 0.0
    relief = np.fft.irfft2(spectrum, s=(size, size))
    relief *= 8.0 / relief.std()
    rows, cols = np.indices((size, size), dtype=np.float64)
    for _ in range(max(4, size * size // 40_000)):
        r0, c0 = rng.uniform(0, size, 2)
        radius = rng.uniform(8.0, 60.0)
        d2 = ((rows - r0) ** 2 + (cols - c0) ** 2) / radius**2
        inside = d2 < 1.0
        relief[inside] -= 0.2 * radius * (1.0 - d2[inside])  # bowl of depth/diameter 0.1
    return relief


def _write(path: Path, values: np.ndarray) -> Path:
    from demtool import io as dio

    dio.write_raster(path, np.asarray(values, dtype=np.float32),
                     transform=dio.image_frame_transform(1.0))
    return path


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    diff = (np.asarray(a, np.float64) - np.asarray(b, np.float64))
    diff = diff[np.isfinite(diff)]
    return float(np.sqrt(np.mean(diff**2))) if diff.size else float("nan")


# --- refine ------------------------------------------------------------------------------

def _refine_prepare(folder: Path, size: int) -> dict:
    from scipy import ndimage

    from demtool.refine.shading import make_illumination, render_dem, sun_from_angles

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(2)
    truth = truth_surface(size)
    field = ndimage.gaussian_filter(rng.normal(size=truth.shape), 40.0)
    albedo = 0.12 * (1.0 + 0.1 * field / field.std())  # ±10 % (1σ), 100-cell scale
    light = make_illumination(sun_from_angles(SUN_AZIMUTH, SUN_ELEVATION))
    image = render_dem(truth, (1.0, 1.0), light, albedo=albedo)
    image = image * (1.0 + 0.01 * rng.normal(size=truth.shape))
    coarse = ndimage.gaussian_filter(truth, 6.0) + rng.normal(0.0, 0.2, truth.shape)
    return {"image": _write(folder / "image.tif", image),
            "coarse": _write(folder / "coarse.tif", coarse),
            "truth": _write(folder / "truth.tif", truth)}


def _refine_command(inputs: dict, out: Path) -> list[str]:
    return [DEMTOOL, "refine", str(inputs["image"]), str(inputs["coarse"]), "--out", str(out),
            "--sun-azimuth", str(SUN_AZIMUTH), "--sun-elevation", str(SUN_ELEVATION),
            "--iterations", str(REFINE_ITERATIONS)]


def _refine_quality(inputs: dict, out: Path) -> dict[str, str]:
    from demtool import io as dio

    truth = dio.read_raster(inputs["truth"]).data
    before = _rmse(dio.read_raster(inputs["coarse"]).data, truth)
    after = _rmse(dio.read_raster(out).data, truth)
    return {"RMSE vs truth before → after (m)": f"{before:.3f} → {after:.3f}"}


def _refine_agreement(inputs: dict, untiled: Path, tiled: Path) -> str:
    from demtool import io as dio

    rmse = _rmse(dio.read_raster(tiled).data, dio.read_raster(untiled).data)
    return f"RMSE of tiled − untiled {rmse:.4f} GSD (issue 15: < 0.02)"


register(ScaleCase(
    stage="refine", result="53_scale_out_refine",
    title=lambda size, tile: (
        f"Scale-out of refine ({size}² grid, lunar-Lambert rendering of a known relief, "
        f"{REFINE_ITERATIONS} iterations): untiled vs tiles on 1 and 2 workers"),
    prepare=_refine_prepare, command=_refine_command, quality=_refine_quality,
    agreement=_refine_agreement, phases=("prepare_dem", "sfs"), tile_size=TILE))


# --- fuse --------------------------------------------------------------------------------

def _fuse_prepare(folder: Path, size: int) -> dict:
    from scipy import ndimage

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    truth = truth_surface(size)
    dems = []
    for i, offset in enumerate(FUSE_OFFSETS):
        dem = truth + offset + rng.normal(0.0, 0.3, truth.shape)
        holes = ndimage.binary_dilation(rng.random(truth.shape) < 2e-4, iterations=6)
        dem[holes] = np.nan
        dem[:, :size * (i + 1) // 20] = np.nan
        dems.append(_write(folder / f"dem_{i}.tif", dem))
    return {"dems": dems, "truth": _write(folder / "truth.tif", truth)}


def _fuse_command(inputs: dict, out: Path) -> list[str]:
    return [DEMTOOL, "fuse", *map(str, inputs["dems"]), "--out", str(out)]


def _fuse_quality(inputs: dict, out: Path) -> dict[str, str]:
    from demtool import io as dio

    fused = dio.read_raster(out).data
    truth = dio.read_raster(inputs["truth"]).data + FUSE_OFFSETS[0]  # the reference's level
    return {"RMSE vs truth (m)": f"{_rmse(fused, truth):.3f}",
            "completeness %": f"{100 * float(np.isfinite(fused).mean()):.2f}"}


def _fuse_agreement(inputs: dict, untiled: Path, tiled: Path) -> str:
    return raster_agreement(untiled, tiled, 1e-4, "m")


register(ScaleCase(
    stage="fuse", result="53_scale_out_fuse",
    title=lambda size, tile: (
        f"Scale-out of fuse (three {size}² DEMs with holes, 0.3 m noise, offsets 0/0.5/1 m; "
        "huber, nuth-kaab): untiled vs tiles on 1 and 2 workers"),
    prepare=_fuse_prepare, command=_fuse_command, quality=_fuse_quality,
    agreement=_fuse_agreement, phases=("coregister", "consensus", "combine"),
    tile_size=TILE))


# --- compare -----------------------------------------------------------------------------

def _compare_prepare(folder: Path, size: int) -> dict:
    from scipy import ndimage

    folder.mkdir(parents=True, exist_ok=True)
    truth = truth_surface(size)
    dx, dy, dz = COMPARE_SHIFT
    dem = ndimage.shift(truth, (dy, dx), order=3, mode="nearest") + dz
    dem += np.random.default_rng(4).normal(0.0, 0.05, truth.shape)
    return {"dem": _write(folder / "dem.tif", dem),
            "truth": _write(folder / "truth.tif", truth)}


def _compare_command(inputs: dict, out: Path) -> list[str]:
    return [DEMTOOL, "compare", str(inputs["dem"]), str(inputs["truth"]), "--out", str(out)]


def _compare_quality(inputs: dict, out: Path) -> dict[str, str]:
    import json

    report = json.loads((out / "report.json").read_text())
    shift = report["shift"]
    return {"shift found (dx, dy, dz)": f"{shift['dx_px']:+.3f}, {shift['dy_px']:+.3f}, "
                                        f"{shift['dz']:+.3f}",
            "shift applied": ", ".join(f"{-v:+.3f}" for v in COMPARE_SHIFT),
            "NMAD (m)": f"{report['nmad']:.4f}"}


register(ScaleCase(
    stage="compare", result="53_scale_out_compare",
    title=lambda size, tile: (
        f"compare on every core ({size}² DEM against its truth, shifted −1.3/+0.7 cells and "
        "+2 m): the untiled run's phases"),
    prepare=_compare_prepare, command=_compare_command, quality=_compare_quality,
    agreement=lambda inputs, untiled, tiled: "—", phases=("read", "compare", "figures"),
    tile_size=0, suffix="", sidecar="report.json.json"))


# --- compare's windowed path -----------------------------------------------------------

WINDOW = 1024  # bench/nac_full.py's --tile-size


def _windowed_prepare(folder: Path, size: int) -> dict:
    from affine import Affine
    from pyproj import Transformer
    from scipy import ndimage

    from demtool import io as dio
    from demtool.maps import body_by_name
    from demtool.maps.projections import make_projection

    folder.mkdir(parents=True, exist_ok=True)
    moon = body_by_name("Moon")
    truth_crs = make_projection(moon, "equirectangular", 0.0, 20.0)
    dem_crs = make_projection(moon, "equirectangular", 0.01, 20.2)
    truth = truth_surface(size)  # on 2 m cells, x from −size to size metres
    truth_transform = Affine(2.0, 0, -float(size), 0, -2.0, float(size))
    to_dem = Transformer.from_crs(truth_crs, dem_crs, always_xy=True)
    x0, y0 = to_dem.transform(-size / 2.0, float(size))
    rows, cols = 2 * size, size
    dem_transform = Affine(1.0, 0, x0, 0, -1.0, y0)
    dx, dy, dz = COMPARE_SHIFT
    dem = np.empty((rows, cols), dtype=np.float32)
    noise = np.random.default_rng(4)
    for start in range(0, rows, 1024):  # DEM cells -> truth cells, in blocks of rows
        stop = min(rows, start + 1024)
        c, r = np.meshgrid(np.arange(cols) + 0.5, np.arange(start, stop) + 0.5)
        x, y = to_dem.transform(x0 + c, y0 - r, direction="INVERSE")
        at = [(size - y) / 2.0 - 0.5 - dy, (x + size) / 2.0 - 0.5 - dx]
        dem[start:stop] = ndimage.map_coordinates(truth, at, order=3, mode="nearest") + dz \
            + noise.normal(0.0, 0.05, c.shape)
    c, r = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    x, y = to_dem.transform(-size + 2.0 * c, size - 2.0 * r)
    inside = (x > x0 + 8) & (x < x0 + cols - 8) & (y < y0 - 8) & (y > y0 - rows + 8)
    truth = np.where(inside, truth, np.nan)
    dio.write_raster(folder / "dem.tif", dem, transform=dem_transform, crs=dem_crs.to_wkt())
    dio.write_raster(folder / "truth.tif", truth.astype(np.float32),
                     transform=truth_transform, crs=truth_crs.to_wkt())
    return {"dem": folder / "dem.tif", "truth": folder / "truth.tif",
            "window": WINDOW if size >= 2 * WINDOW else max(16, size // 2)}


def _windowed_command(inputs: dict, out: Path) -> list[str]:
    return [DEMTOOL, "compare", str(inputs["dem"]), str(inputs["truth"]), "--tile-size",
            str(inputs["window"]), "--out", str(out)]


def _windowed_quality(inputs: dict, out: Path) -> dict[str, str]:
    import json

    report = json.loads((out / "report.json").read_text())
    windowed = report.get("windowed", {})
    shift = report["shift"]
    return {"windows, passes": f"{windowed.get('windows', '—')}, "
                               f"{windowed.get('passes', '—')}",
            "shift found (dx, dy truth cells, dz)": f"{shift['dx_px']:+.3f}, "
                                                    f"{shift['dy_px']:+.3f}, "
                                                    f"{shift['dz']:+.3f}",
            "shift applied": ", ".join(f"{-v:+.3f}" for v in COMPARE_SHIFT),
            "NMAD (m)": f"{report['nmad']:.4f}", "completeness %":
            f"{report['completeness']:.2f}"}


register(ScaleCase(
    stage="compare-windowed", result="53_scale_out_compare_windowed",
    title=lambda size, tile: (
        f"compare's windowed path on every core ({size}² truth of 2 m against a "
        f"{2 * size} × {size} DEM of 1 m on another map projection, shifted −1.3/+0.7 "
        f"truth cells and +2 m, windows of {WINDOW if size >= 2 * WINDOW else size // 2}):"
        " its phases"),
    prepare=_windowed_prepare, command=_windowed_command, quality=_windowed_quality,
    agreement=lambda inputs, untiled, tiled: "—",
    phases=("read", "align", "statistics", "figures"), tile_size=0, suffix="",
    sidecar="report.json.json", untiled_label="windowed"))
