"""The bad-input matrix (issue 16): each case through the CLI on tiny files in tmp_path.

Every case must end with the expected exit status (1 for bad input, 2 for usage),
exactly one ``Error:`` line, no traceback, nothing written, and every input file
byte-identical afterwards.  For every stage the table holds at least: a missing input,
an empty and a truncated file, a file of the wrong kind, an output over an input, two
outputs on one path, an output folder that cannot be written, a NaN/inf option, and
the stage's own nonsense (constant images, a rectification of another pair,
disparities of 1e27, masks of another grid ...).  Stages without input files
(``synth``) or with a single output (``rectify``, ``compare`` write one folder;
``select`` one file) skip the cases that cannot apply.  Every case fails in
milliseconds, before any matching or COLMAP run.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli

SGM_RANGE = ["--min-disparity", "0", "--num-disparities", "8", "--mi-iterations", "1"]
SUN = ["--sun-azimuth", "30", "--sun-elevation", "40"]


def _rect_arrays(size=(64, 48), disparity_range=(0.0, 7.0)):
    points = np.array([[10.0, 10.0], [30.0, 20.0], [50.0, 40.0]])
    return {"H_left": np.eye(3), "H_right": np.eye(3), "F": np.zeros((3, 3)),
            "size_left": np.array(size), "size_right": np.array(size),
            "size_rect": np.array(size), "points_left": points, "points_right": points,
            "points_left_rect": points, "points_right_rect": points,
            "disparity_range": np.array(disparity_range), "left_name": np.asarray("left"),
            "right_name": np.asarray("right")}


def _texture(shape, seed=0):
    """Smooth random texture (Gaussian low-pass of white noise), 0 … 255 DN."""
    rng = np.random.default_rng(seed)
    spectrum = np.fft.fft2(rng.standard_normal(shape))
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    smooth = np.fft.ifft2(spectrum * np.exp(-(fx**2 + fy**2) / (2 * 0.08**2))).real
    smooth = (smooth - smooth.min()) / np.ptp(smooth)
    return (20 + 200 * smooth).astype(np.float32)


@pytest.fixture
def work(tmp_path, monkeypatch):
    """Tiny inputs: a textured pair, constant images, rectify files, disparities, DEMs."""
    import rasterio
    from affine import Affine

    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(0)
    left = _texture((48, 64))
    right = np.roll(left, -3, axis=1)  # x_right = x_left - 3
    dio.write_raster("left.tif", left, tags={"frame": "image:left_rect"})
    dio.write_raster("right.tif", right, tags={"frame": "image:right_rect"})
    dio.write_raster("flat.tif", np.full((48, 64), 100.0, np.float32))
    dio.write_raster("zeros.tif", np.zeros((48, 64), np.float32))
    dio.write_npz("rect.npz", "rectification", _rect_arrays())
    dio.write_npz("other_rect.npz", "rectification", _rect_arrays(size=(200, 150)))
    dio.write_raster("d.tif", np.full((48, 64), 3.0, np.float32),
                     tags={"frame": "image:left_rect"})
    dio.write_raster("d_1e27.tif", np.full((48, 64), 1e27, np.float32))
    dio.write_raster("d_other_pair.tif", np.full((48, 64), 3.0, np.float32),
                     tags={"frame": "image:view_07_rect"})
    for name, count, dtype, values in (("d_uint16.tif", 1, "uint16", rng.integers(0, 65535,
                                                                                   (1, 48, 64))),
                                       ("rgb.tif", 3, "uint8", rng.integers(0, 255,
                                                                            (3, 48, 64)))):
        with rasterio.open(name, "w", driver="GTiff", width=64, height=48, count=count,
                           dtype=dtype, transform=Affine(1, 0, 0, 0, -1, 48)) as ds:
            ds.write(values.astype(dtype))
    dio.write_raster("ref.tif", rng.normal(0, 5, (48, 64)),
                     transform=dio.image_frame_transform(2), tags={"frame": "image:left"})
    dio.write_raster("ref_1e27.tif", np.full((48, 64), 1e27),
                     transform=dio.image_frame_transform(2), tags={"frame": "image:left"})
    dio.write_raster("dem.tif", rng.normal(0, 5, (32, 32)), transform=dio.image_frame_transform(2))
    dio.write_raster("dem_img.tif", _texture((48, 64), seed=3) / 20,
                     transform=dio.image_frame_transform(2))
    dio.write_raster("small_mask.tif", np.ones((16, 16)), transform=dio.image_frame_transform(2))
    Path("empty.tif").write_bytes(b"")
    Path("empty.npz").write_bytes(b"")
    Path("truncated.tif").write_bytes(Path("left.tif").read_bytes()[:300])
    Path("truncated.npz").write_bytes(Path("rect.npz").read_bytes()[:200])
    Path("notes.tif").write_text("these are notes, not a raster\n")
    Path("scene").mkdir()
    Path("pair").mkdir()
    shutil.copy("left.tif", "pair/left_rect.tif")
    Path("cmp_in").mkdir()
    shutil.copy("dem.tif", "cmp_in/difference.tif")
    Path("a_file").write_text("not a folder\n")
    os.symlink("left.tif", "link_to_left.tif")
    os.link("right.tif", "hard_link_to_right.tif")
    os.symlink("o.tif", "dangling_link_to_o.tif")
    selection = {"target": {"name": "left", "path": "left.tif"},
                 "selected": [{"name": "left", "path": "left.tif"},
                              {"name": "right", "path": "right.tif"}]}
    Path("selection.json").write_text(json.dumps(selection))
    Path("truncated.json").write_text(json.dumps(selection)[:40])
    Path("empty.json").write_text("")
    Path("other.json").write_text('{"views": 3}')
    Path("missing_image.json").write_text(json.dumps(
        {"target": {"name": "left", "path": "left.tif"},
         "selected": [{"name": "left", "path": "left.tif"},
                      {"name": "gone", "path": "gone.tif"}]}))
    _write_bad_sensors()
    Path("list.toml").write_text("[dem]\nmedian = [1, 2]\n")
    Path("inf.toml").write_text("[sgm]\nlr-threshold = inf\n")
    Path("string.toml").write_text("[synth]\nsize = \"big\"\n")
    return tmp_path


def _write_bad_sensors():
    """A frame ISD over (10°E, 5°N) for the 48 x 64 px images, and broken copies of it
    (issue 31: values checked, not only keys)."""
    from tests.helpers.camera_isd import nadir_isd
    from tests.helpers.linescan import isd_dict, linescan_sensor

    good = nadir_isd(10.0, 5.0, 50_000.0, focal_mm=50.0, pitch_mm=0.01, lines=48, samples=64)
    Path("cam.json").write_text(json.dumps(good))

    def bad(name, edit):
        isd = json.loads(json.dumps(good))
        edit(isd)
        Path(name).write_text(json.dumps(isd))

    bad("cam_focal_nan.json", lambda d: d["focal_length_model"].update(focal_length=float("nan")))
    bad("cam_focal_zero.json", lambda d: d["focal_length_model"].update(focal_length=0.0))
    bad("cam_singular.json", lambda d: d.update(focal2pixel_lines=[0.0, 0.0, 0.0]))
    bad("cam_zero_quaternion.json",
        lambda d: d["instrument_pointing"].update(quaternions=[[0.0, 0.0, 0.0, 0.0]]))
    bad("cam_mirror.json", lambda d: d["instrument_pointing"].update(
        constant_rotation=[1.0, 0, 0, 0, 1.0, 0, 0, 0, -1.0]))
    bad("cam_sheared.json", lambda d: d["instrument_pointing"].update(
        constant_rotation=[1.0, 0.3, 0, 0, 1.0, 0, 0, 0, 1.0]))
    bad("cam_km_as_m.json", lambda d: d["instrument_position"].update(
        positions=[[v / 1000.0 for v in d["instrument_position"]["positions"][0]]]))
    bad("cam_radii_null.json", lambda d: d["radii"].update(semimajor=None))
    bad("cam_radii_string.json", lambda d: d["radii"].update(semiminor="1737.4"))
    bad("cam_lines_nan.json", lambda d: d.update(image_lines=float("nan")))
    bad("cam_lines_zero.json", lambda d: d.update(image_lines=0))
    bad("cam_lines_string.json", lambda d: d.update(image_lines="48"))
    bad("cam_mars_radii.json", lambda d: d.update(naif_keywords={"BODY_CODE": 499}))
    scan = isd_dict(linescan_sensor(lines=48, samples=64))
    scan["line_scan_rate"] = [[r[0], r[1], -r[2]] for r in scan["line_scan_rate"]]
    Path("ls_backwards.json").write_text(json.dumps(scan))
    scan = isd_dict(linescan_sensor(lines=48, samples=64))
    scan["instrument_position"] = {"ephemeris_times": [1000.0], "unit": "m",
                                   "positions": [scan["instrument_position"]["positions"][20]]}
    Path("ls_one_state.json").write_text(json.dumps(scan))
    Path("only_label.cub").write_text("Object = IsisCube\n")
    from demtool.maps import body_by_name, grid_from_lonlat

    moon = body_by_name("Moon")
    grid = grid_from_lonlat(moon, np.array([9.95, 10.05]), np.array([4.95, 5.05]), 20.0)
    shape = (grid.height, grid.width)
    for name, values in (("map_dem_nan.tif", np.full(shape, np.nan)),
                         ("map_dem_1e27.tif", np.full(shape, 1e27)),
                         # radii of Mars's size on a Moon map: read as radii, still
                         # 1652 km above the Moon's sphere
                         ("map_dem_radius.tif", np.full(shape, 3389500.0))):
        dio.write_raster(name, values, transform=grid.transform, crs=grid.crs)


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


SYNTH_TINY = ["--size", "32", "--image-size", "32", "--views", "2", "--craters", "0",
              "--boulders", "0"]
SGM = ["sgm", "left.tif", "right.tif"]
MATCH = ["match", "left.tif", "right.tif"]
DEM = ["dem", "--rectify", "rect.npz", "--reference", "ref.tif"]
REFINE = ["refine", "left.tif", "dem_img.tif", *SUN]
COMPARE = ["compare", "dem.tif", "dem.tif", "--no-plots"]
SELECT = ["select", "left.tif", "right.tif", "--target", "left.tif"]


def case(name, argv, status, message):
    return pytest.param(name, argv, status, message, id=name)


# (id, argv after `demtool`, expected exit status, text the Error: line must contain)
CASES = [
    # ---------------------------------------------------------------- synth (no input files)
    case("synth-out-under-a-file", ["synth", "--out", "a_file/scene", *SYNTH_TINY], 1,
         "cannot create the folder a_file/scene: a_file is a file"),
    case("synth-out-is-a-file", ["synth", "--out", "a_file", *SYNTH_TINY], 1,
         "a_file: --out is a file, expected a folder"),
    case("synth-out-in-proc", ["synth", "--out", "/proc/scene", *SYNTH_TINY], 1,
         "/proc/scene: cannot create /proc/scene in the folder /proc"),
    case("synth-sun-azimuth-nan", ["synth", "--out", "s", "--sun-azimuth", "nan"], 2,
         "'--sun-azimuth': 'nan' is not a finite number."),
    case("synth-exposure-inf", ["synth", "--out", "s", "--exposure", "inf"], 2,
         "'--exposure': 'inf' is not a finite number."),
    case("synth-size-too-small", ["synth", "--out", "s", "--size", "4"], 2,
         "'--size'"),
    case("preset-string-for-int", ["--config", "string.toml", "synth", "--out", "s"], 2,
         "preset string.toml, [synth] size = 'big': 'big' is not a valid integer."),
    # ---------------------------------------------------------------- select
    case("select-missing-image", ["select", "left.tif", "gone.tif", "--target", "gone.tif",
                                  "--out", "s.json"], 1, "gone.tif"),
    case("select-empty-target", ["select", "left.tif", "--target", "empty.tif", "--out",
                                 "s.json"], 1, "empty.tif"),
    case("select-truncated-target", ["select", "left.tif", "--target", "truncated.tif",
                                     "--out", "s.json"], 1, "truncated.tif"),
    case("select-wrong-kind-target", ["select", "left.tif", "--target", "rect.npz", "--out",
                                      "s.json"], 1, "rect.npz"),
    case("select-out-over-target", [*SELECT, "--out", "left.tif"], 1,
         "would overwrite the input --target left.tif"),
    case("select-out-over-image", [*SELECT, "--out", "./right.tif"], 1,
         "would overwrite the input IMAGES"),
    case("select-out-in-proc", [*SELECT, "--out", "/proc/s.json"], 1,
         "/proc/s.json: cannot write in the folder /proc"),
    case("select-ratio-nan", [*SELECT, "--out", "s.json", "--ratio", "nan"], 2,
         "'--ratio': 'nan' is not a finite number."),
    case("select-roi-nan", [*SELECT, "--roi", "0", "0", "nan", "10", "--out", "s.json"], 2,
         "'--roi': 'nan' is not a finite number."),
    # ---------------------------------------------------------------- bundle
    case("bundle-missing-selection", ["bundle", "gone.json", "--out", "b.npz"], 1,
         "gone.json"),
    case("bundle-empty-selection", ["bundle", "empty.json", "--out", "b.npz"], 1,
         "empty.json"),
    case("bundle-truncated-selection", ["bundle", "truncated.json", "--out", "b.npz"], 1,
         "truncated.json"),
    case("bundle-wrong-kind-selection", ["bundle", "other.json", "--out", "b.npz"], 1,
         "other.json: not a selection file"),
    case("bundle-selection-names-missing-image", ["bundle", "missing_image.json", "--out",
                                                  "b.npz"], 1, "gone.tif"),
    case("bundle-out-over-selection", ["bundle", "selection.json", "--out", "selection.json"],
         1, "would overwrite the input SELECTION selection.json"),
    case("bundle-out-over-an-image", ["bundle", "left.tif", "right.tif", "--out", "right.tif"],
         1, "would overwrite the input"),
    case("bundle-out-and-colmap-dir", ["bundle", "selection.json", "--out", "b.npz",
                                       "--colmap-dir", "b.npz"], 1, "name the same file"),
    case("bundle-out-in-proc", ["bundle", "selection.json", "--out", "/proc/b.npz"], 1,
         "/proc/b.npz: cannot write in the folder /proc"),
    case("bundle-focal-nan", ["bundle", "selection.json", "--out", "b.npz", "--focal-px",
                              "nan"], 2, "'--focal-px': 'nan' is not a finite number."),
    # ---------------------------------------------------------------- rectify
    case("rectify-missing-left", ["rectify", "gone.tif", "right.tif", "--out", "r"], 1,
         "gone.tif"),
    case("rectify-empty-left", ["rectify", "empty.tif", "right.tif", "--out", "r"], 1,
         "empty.tif"),
    case("rectify-truncated-right", ["rectify", "left.tif", "truncated.tif", "--out", "r"], 1,
         "truncated.tif"),
    case("rectify-wrong-kind", ["rectify", "rect.npz", "right.tif", "--out", "r"], 1,
         "rect.npz"),
    case("rectify-text-as-image", ["rectify", "left.tif", "notes.tif", "--out", "r"], 1,
         "notes.tif"),
    case("rectify-out-over-input", ["rectify", "pair/left_rect.tif", "right.tif", "--out",
                                    "pair"], 1, "would overwrite the input LEFT"),
    case("rectify-out-is-a-file", ["rectify", "left.tif", "right.tif", "--out", "a_file"], 1,
         "a_file: --out is a file, expected a folder"),
    case("rectify-out-in-proc", ["rectify", "left.tif", "right.tif", "--out", "/proc/r"], 1,
         "cannot create /proc/r in the folder /proc"),
    case("rectify-ratio-nan", ["rectify", "left.tif", "right.tif", "--out", "r", "--ratio",
                               "nan"], 2, "'--ratio': 'nan' is not a finite number."),
    case("rectify-constant-image", ["rectify", "flat.tif", "right.tif", "--out", "r"], 1,
         "flat.tif: left image has no usable texture (every valid pixel is 100)"),
    case("rectify-all-zero-image", ["rectify", "left.tif", "zeros.tif", "--out", "r"], 1,
         "zeros.tif: right image has no usable texture (every valid pixel is 0)"),
    # ---------------------------------------------------------------- sgm
    case("sgm-missing-left", ["sgm", "gone.tif", "right.tif", "--out", "d2.tif", *SGM_RANGE],
         1, "gone.tif"),
    case("sgm-empty-right", ["sgm", "left.tif", "empty.tif", "--out", "d2.tif", *SGM_RANGE],
         1, "empty.tif"),
    case("sgm-truncated-left", ["sgm", "truncated.tif", "right.tif", "--out", "d2.tif",
                                *SGM_RANGE], 1, "truncated.tif"),
    case("sgm-wrong-kind-rectify", [*SGM, "--rectify", "left.tif", "--out", "d2.tif"], 1,
         "left.tif"),
    case("sgm-truncated-rectify", [*SGM, "--rectify", "truncated.npz", "--out", "d2.tif"], 1,
         "truncated.npz"),
    case("sgm-out-over-left", [*SGM, "--out", "left.tif", *SGM_RANGE], 1,
         "would overwrite the input LEFT_RECT left.tif"),
    case("sgm-out-over-rectify", [*SGM, "--rectify", "rect.npz", "--out", "rect.npz"], 1,
         "would overwrite the input --rectify rect.npz"),
    case("sgm-out-over-left-other-spelling", [*SGM, "--out", "scene/../left.tif", *SGM_RANGE],
         1, "would overwrite the input"),
    case("sgm-out-on-a-symlink-to-left", [*SGM, "--out", "link_to_left.tif", *SGM_RANGE], 1,
         "link_to_left.tif: --out would overwrite the input LEFT_RECT left.tif"),
    case("sgm-confidence-on-a-hard-link-to-right", [*SGM, "--out", "d2.tif", "--confidence",
                                                    "hard_link_to_right.tif", *SGM_RANGE], 1,
         "--confidence would overwrite the input RIGHT_RECT right.tif"),
    case("dem-mask-on-a-symlink-to-out", [*DEM, "--disparity", "d.tif", "--out", "o.tif",
                                          "--interpolated-mask", "dangling_link_to_o.tif"], 1,
         "--out and --interpolated-mask name the same file"),
    case("sgm-confidence-on-out", [*SGM, "--out", "d2.tif", "--confidence", "scene/../d2.tif",
                                   *SGM_RANGE], 1, "name the same file"),
    case("sgm-confidence-over-right", [*SGM, "--out", "d2.tif", "--confidence", "right.tif",
                                       *SGM_RANGE], 1, "would overwrite the input RIGHT_RECT"),
    case("sgm-out-in-proc", [*SGM, "--out", "/proc/d.tif", *SGM_RANGE], 1,
         "/proc/d.tif: cannot write"),
    case("sgm-out-under-a-file", [*SGM, "--out", "a_file/d.tif", *SGM_RANGE], 1,
         "a_file/d.tif: cannot write the output: a_file is a file"),
    case("sgm-lr-threshold-nan", [*SGM, "--out", "d2.tif", "--lr-threshold", "nan",
                                  *SGM_RANGE], 2,
         "'--lr-threshold': 'nan' is not a finite number."),
    case("preset-inf", ["--config", "inf.toml", *SGM, "--out", "d2.tif", *SGM_RANGE], 2,
         "preset inf.toml, [sgm] lr-threshold = inf: inf is not a finite number."),
    case("sgm-constant-image", ["sgm", "flat.tif", "right.tif", "--out", "d2.tif",
                                *SGM_RANGE], 1, "flat.tif: left image has no usable texture"),
    case("sgm-all-zero-image", ["sgm", "left.tif", "zeros.tif", "--out", "d2.tif",
                                *SGM_RANGE], 1, "zeros.tif: right image has no usable texture"),
    case("sgm-rectify-of-another-pair", [*SGM, "--rectify", "other_rect.npz", "--out",
                                         "d2.tif"], 1, "is it the rectification of this pair"),
    case("sgm-images-of-different-size", ["sgm", "left.tif", "dem.tif", "--out", "d2.tif",
                                          *SGM_RANGE], 1, "differ in size"),
    # ---------------------------------------------------------------- match
    case("match-missing-right", ["match", "left.tif", "gone.tif", "--out", "d2.tif"], 1,
         "gone.tif"),
    case("match-empty-left", ["match", "empty.tif", "right.tif", "--out", "d2.tif"], 1,
         "empty.tif"),
    case("match-truncated-right", ["match", "left.tif", "truncated.tif", "--out", "d2.tif"],
         1, "truncated.tif"),
    case("match-wrong-kind-rectify", [*MATCH, "--rectify", "right.tif", "--out", "d2.tif"], 1,
         "right.tif"),
    case("match-empty-rectify", [*MATCH, "--rectify", "empty.npz", "--out", "d2.tif"], 1,
         "empty.npz"),
    case("match-out-over-right", [*MATCH, "--out", "right.tif"], 1,
         "would overwrite the input RIGHT right.tif"),
    case("match-out-over-rectify", [*MATCH, "--rectify", "rect.npz", "--out", "rect.npz"], 1,
         "would overwrite the input --rectify rect.npz"),
    case("match-correlation-on-sigma", [*MATCH, "--out", "d2.tif", "--correlation-out",
                                        "c.tif", "--sigma-out", "c.tif"], 1,
         "name the same file"),
    case("match-out-on-its-sidecar", [*MATCH, "--out", "d2.tif", "--sigma-out",
                                      "d2.tif.json"], 1, "name the same file"),
    case("match-out-in-proc", [*MATCH, "--out", "/proc/d.tif"], 1,
         "/proc/d.tif: cannot write in the folder /proc"),
    case("match-threshold-nan", [*MATCH, "--out", "d2.tif", "--threshold", "nan"], 2,
         "'--threshold': 'nan' is not a finite number."),
    case("match-constant-image", ["match", "left.tif", "flat.tif", "--out", "d2.tif"], 1,
         "flat.tif: right image has no usable texture"),
    case("match-rectify-of-another-pair", [*MATCH, "--rectify", "other_rect.npz", "--out",
                                           "d2.tif"], 1, "other_rect.npz"),
    # ---------------------------------------------------------------- dem
    case("dem-missing-disparity", [*DEM, "--disparity", "gone.tif", "--out", "o.tif"], 1,
         "gone.tif"),
    case("dem-empty-disparity", [*DEM, "--disparity", "empty.tif", "--out", "o.tif"], 1,
         "empty.tif"),
    case("dem-truncated-rectify", ["dem", "--rectify", "truncated.npz", "--reference",
                                   "ref.tif", "--disparity", "d.tif", "--out", "o.tif"], 1,
         "truncated.npz"),
    case("dem-wrong-kind-disparity", [*DEM, "--disparity", "rect.npz", "--out", "o.tif"], 1,
         "rect.npz"),
    case("dem-out-over-disparity", [*DEM, "--disparity", "d.tif", "--out", "d.tif"], 1,
         "would overwrite the input --disparity d.tif"),
    case("dem-mask-on-out", [*DEM, "--disparity", "d.tif", "--out", "o.tif",
                             "--interpolated-mask", "o.tif"], 1,
         "--out and --interpolated-mask name the same file"),
    case("dem-mask-over-reference", [*DEM, "--disparity", "d.tif", "--out", "o.tif",
                                     "--interpolated-mask", "ref.tif"], 1,
         "would overwrite the input --reference ref.tif"),
    case("dem-out-in-proc", [*DEM, "--disparity", "d.tif", "--out", "/proc/o.tif"], 1,
         "/proc/o.tif: cannot write in the folder /proc"),
    case("dem-gsd-inf", [*DEM, "--disparity", "d.tif", "--gsd", "inf", "--out", "o.tif"], 2,
         "'--gsd': 'inf' is not a finite number."),
    case("dem-outlier-threshold-negative", [*DEM, "--disparity", "d.tif",
                                            "--outlier-threshold", "-1", "--out", "o.tif"], 2,
         "-1.0 is not in the range x>=0.0."),
    case("preset-median-list", ["--config", "list.toml", *DEM, "--disparity", "d.tif",
                                "--out", "o.tif"], 2,
         "preset list.toml, [dem] median = [1, 2]: expected one integer, got a list"),
    case("dem-disparities-1e27", [*DEM, "--disparity", "d_1e27.tif", "--out", "o.tif"], 1,
         "d_1e27.tif: 100 % of the disparities lie outside"),
    case("dem-uint16-as-disparity", [*DEM, "--disparity", "d_uint16.tif", "--out", "o.tif"],
         1, "of the disparities lie outside"),
    case("dem-rgb-as-disparity", [*DEM, "--disparity", "rgb.tif", "--out", "o.tif"], 1,
         "of the disparities lie outside"),
    case("dem-reference-1e27", ["dem", "--rectify", "rect.npz", "--reference", "ref_1e27.tif",
                                "--disparity", "d.tif", "--out", "o.tif"], 1,
         "ref_1e27.tif: reference DEM has 3072 value(s) beyond"),
    case("dem-disparity-of-another-pair", [*DEM, "--disparity", "d_other_pair.tif", "--out",
                                           "o.tif"], 1,
         "d_other_pair.tif: disparity in frame image:view_07_rect, but rect.npz rectifies left"),
    case("dem-rectify-of-another-pair", ["dem", "--rectify", "other_rect.npz", "--reference",
                                         "ref.tif", "--disparity", "d.tif", "--out", "o.tif"],
         1, "other_rect.npz"),
    # ---------------------------------------------------------------- refine
    case("refine-missing-dem", ["refine", "left.tif", "gone.tif", "--out", "r.tif", *SUN], 1,
         "gone.tif"),
    case("refine-empty-image", ["refine", "empty.tif", "dem_img.tif", "--out", "r.tif", *SUN],
         1, "empty.tif"),
    case("refine-truncated-dem", ["refine", "left.tif", "truncated.tif", "--out", "r.tif",
                                  *SUN], 1, "truncated.tif"),
    case("refine-wrong-kind-dem", ["refine", "left.tif", "rect.npz", "--out", "r.tif", *SUN],
         1, "rect.npz"),
    case("refine-out-over-dem", [*REFINE, "--out", "dem_img.tif"], 1,
         "would overwrite the input DEM dem_img.tif"),
    case("refine-albedo-on-out", [*REFINE, "--out", "r.tif", "--albedo-out", "r.tif"], 1,
         "--out and --albedo-out name the same file"),
    case("refine-albedo-over-image", [*REFINE, "--out", "r.tif", "--albedo-out", "left.tif"],
         1, "would overwrite the input IMAGE left.tif"),
    case("refine-out-in-proc", [*REFINE, "--out", "/proc/r.tif"], 1,
         "/proc/r.tif: cannot write in the folder /proc"),
    case("refine-sun-azimuth-inf", ["refine", "left.tif", "dem.tif", "--out", "r.tif",
                                    "--sun-azimuth", "-inf"], 2,
         "'--sun-azimuth': '-inf' is not a finite number."),
    case("refine-all-zero-image", ["refine", "zeros.tif", "dem_img.tif", "--out", "r.tif",
                                   *SUN], 1,
         "zeros.tif: image has no usable texture (every valid pixel is 0)"),
    case("refine-constant-image", ["refine", "flat.tif", "dem_img.tif", "--out", "r.tif",
                                   *SUN], 1, "flat.tif: image has no usable texture"),
    case("refine-dem-1e27", ["refine", "left.tif", "ref_1e27.tif", "--out", "r.tif", *SUN], 1,
         "ref_1e27.tif: DEM has 3072 value(s) beyond"),
    # ---------------------------------------------------------------- compare
    case("compare-missing-reference", ["compare", "dem.tif", "gone.tif", "--out", "cmp"], 1,
         "gone.tif"),
    case("compare-empty-dem", ["compare", "empty.tif", "dem.tif", "--out", "cmp"], 1,
         "empty.tif"),
    case("compare-truncated-reference", ["compare", "dem.tif", "truncated.tif", "--out",
                                         "cmp"], 1, "truncated.tif"),
    case("compare-wrong-kind-dem", ["compare", "rect.npz", "dem.tif", "--out", "cmp"], 1,
         "rect.npz"),
    case("compare-out-over-input", ["compare", "cmp_in/difference.tif", "dem.tif", "--out",
                                    "cmp_in"], 1, "would overwrite the input DEM"),
    case("compare-out-is-the-dem", [*COMPARE, "--out", "dem.tif"], 1,
         "would overwrite the input"),
    case("sgm-out-is-a-folder", [*SGM, "--out", "scene", *SGM_RANGE], 1,
         "scene: --out is a folder, expected a file name"),
    case("mapproject-out-is-a-folder", ["mapproject", "left.tif", "--sensor", "cam.json",
                                        "--height", "0", "--out", "scene"], 1,
         "scene: --out is a folder, expected a file name"),
    case("mapproject-gsd-1e-5", ["mapproject", "left.tif", "--sensor", "cam.json",
                                 "--height", "0", "--gsd", "1e-5", "--out", "o.tif"], 1,
         "--gsd: the orthoimage would be"),
    case("mapproject-bounds-far-away", ["mapproject", "left.tif", "--sensor", "cam.json",
                                        "--height", "0", "--bounds", "100", "10", "101", "11",
                                        "--out", "o.tif"], 1,
         "--bounds: lon 100…101, lat 10…11 does not overlap the image's footprint"),
    case("mapproject-bounds-latitude-100", ["mapproject", "left.tif", "--sensor", "cam.json",
                                            "--height", "0", "--bounds", "10", "-100", "11",
                                            "10", "--out", "o.tif"], 2,
         "latitudes within +-90"),
    case("mapproject-scheduler-not-an-address", ["mapproject", "left.tif", "--sensor",
                                                 "cam.json", "--height", "0", "--scheduler",
                                                 "nowhere", "--out", "o.tif"], 2,
         "'--scheduler': 'nowhere' is not a scheduler address"),
    case("compare-out-in-proc", [*COMPARE, "--out", "/proc/cmp"], 1,
         "cannot create /proc/cmp in the folder /proc"),
    case("compare-profile-nan", [*COMPARE, "--out", "cmp", "--profile", "0,0,nan,10"], 2,
         "--profile"),
    case("compare-mask-of-another-grid", [*COMPARE, "--mask", "small_mask.tif", "--out",
                                          "cmp"], 1, "they must share one grid"),
    # ---------------------------------------------------------------- sensor models (issue 31)
    case("camera-focal-nan", ["camera", "cam_focal_nan.json"], 1,
         "cam_focal_nan.json: key 'focal_length_model.focal_length' = nan: not a finite number"),
    case("camera-focal-zero", ["camera", "cam_focal_zero.json"], 1,
         "cam_focal_zero.json: key 'focal_length_model.focal_length' = 0: must be positive"),
    case("camera-singular-focal2pixel", ["camera", "cam_singular.json"], 1,
         "cam_singular.json: keys 'focal2pixel_samples/focal2pixel_lines'"),
    case("camera-zero-quaternion", ["camera", "cam_zero_quaternion.json"], 1,
         "key 'instrument_pointing.quaternions' = [0., 0., 0., 0.]: row 0 is all zero"),
    case("camera-sheared-rotation", ["camera", "cam_sheared.json"], 1,
         "key 'instrument_pointing.constant_rotation'"),
    case("camera-km-labelled-m", ["camera", "cam_km_as_m.json"], 1,
         "cam_km_as_m.json: key 'instrument_position.positions'"),
    case("camera-radii-null", ["camera", "cam_radii_null.json"], 1,
         "key 'radii.semimajor' = None: not a number"),
    case("camera-radii-string", ["camera", "cam_radii_string.json"], 1,
         "key 'radii.semiminor' = '1737.4': not a number"),
    case("camera-lines-nan", ["camera", "cam_lines_nan.json"], 1,
         "key 'image_lines' = nan: not a finite number"),
    case("camera-lines-zero", ["camera", "cam_lines_zero.json"], 1,
         "key 'image_lines' = 0: must be positive"),
    case("camera-lines-string", ["camera", "cam_lines_string.json"], 1,
         "key 'image_lines' = '48': not a number"),
    case("camera-moon-radii-on-mars", ["camera", "cam_mars_radii.json"], 1,
         "but the file is of Mars (NAIF 499)"),
    case("camera-body-mars-on-moon", ["camera", "cam.json", "--body", "Mars"], 1,
         "cam.json: its radii (1737.4 km) are not those of --body Mars"),
    case("camera-lines-backwards", ["camera", "ls_backwards.json"], 1,
         "ls_backwards.json: key 'line_scan_rate'"),
    case("camera-one-state-no-velocity", ["camera", "ls_one_state.json"], 1,
         "ls_one_state.json: key 'instrument_position' has one state and no velocity"),
    case("camera-label-only-cube", ["camera", "only_label.cub"], 1,
         "only_label.cub: cannot parse the ISIS label"),
    case("mapproject-mirrored-camera", ["mapproject", "left.tif", "--sensor", "cam_mirror.json",
                                        "--height", "0", "--out", "o.tif"], 1,
         "cam_mirror.json: key 'instrument_pointing.constant_rotation'"),
    case("mapproject-nan-focal", ["mapproject", "left.tif", "--sensor", "cam_focal_nan.json",
                                  "--height", "0", "--out", "o.tif"], 1,
         "cam_focal_nan.json: key 'focal_length_model.focal_length'"),
    case("mapproject-all-nan-dem", ["mapproject", "left.tif", "--sensor", "cam.json",
                                    "--dem", "map_dem_nan.tif", "--out", "o.tif"], 1,
         "map_dem_nan.tif: DEM has no valid height under the image's footprint"),
    case("mapproject-1e27-dem", ["mapproject", "left.tif", "--sensor", "cam.json",
                                 "--dem", "map_dem_1e27.tif", "--out", "o.tif"], 1,
         "map_dem_1e27.tif: DEM heights reach 1e+27 m"),
    case("mapproject-radii-of-another-body", ["mapproject", "left.tif", "--sensor",
                                              "cam.json", "--dem", "map_dem_radius.tif",
                                              "--out", "o.tif"], 1,
         "map_dem_radius.tif: DEM heights reach 1.652e+06 m"),
    case("mapproject-height-below-the-centre", ["mapproject", "left.tif", "--sensor",
                                                "cam.json", "--height", "-2e6", "--out",
                                                "o.tif"], 1,
         "--height -2e+06: beyond"),
    case("mapproject-height-above-the-camera", ["mapproject", "left.tif", "--sensor",
                                                "cam.json", "--height", "60000", "--out",
                                                "o.tif"], 1,
         "--height 60000: at or above the camera"),
    case("bundle-sensor-focal-nan", ["bundle", "left.tif", "right.tif", "--sensors",
                                     "cam_focal_nan.json", "--sensors", "cam.json", "--out",
                                     "b.npz"], 1,
         "cam_focal_nan.json: key 'focal_length_model.focal_length' = nan"),
    case("compare-reference-1e27", ["compare", "ref.tif", "ref_1e27.tif", "--out", "cmp",
                                    "--no-plots"], 1,
         "ref_1e27.tif: reference DEM has 3072 value(s) beyond"),
]


@pytest.mark.parametrize("name, argv, status, message", CASES)
def test_bad_input(work, name, argv, status, message):
    before = _snapshot(work)
    result = CliRunner().invoke(cli, ["-q", *argv])
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    assert result.exit_code == status, result.output
    assert len(errors) == 1, result.output
    assert message in errors[0], errors[0]
    assert "Traceback" not in result.output
    assert not isinstance(result.exception, Exception) or isinstance(result.exception,
                                                                     SystemExit)
    assert _snapshot(work) == before  # nothing written, inputs byte-identical


def test_scaled_int16_reference_reads_in_metres(work):
    """Class 5: an int16 half-metre DEM (GeoTIFF scale 0.5) compared with itself in metres."""
    import rasterio
    from affine import Affine

    heights = np.random.default_rng(1).normal(0, 2000, (32, 32)).round() / 2  # half-metres
    transform = Affine(100.0, 0, 0, 0, -100.0, 0)
    with rasterio.open("ref_int16.tif", "w", driver="GTiff", width=32, height=32, count=1,
                       dtype="int16", nodata=-32768, transform=transform) as ds:
        ds.scales = (0.5,)
        ds.offsets = (0.0,)
        ds.write((heights * 2).astype(np.int16), 1)
    dio.write_raster("dem_m.tif", heights, transform=transform)
    result = CliRunner().invoke(cli, ["-q", "compare", "dem_m.tif", "ref_int16.tif", "--out",
                                      "cmp", "--align", "none", "--no-plots", "--json"])
    assert result.exit_code == 0, result.output
    report = dio.read_json(next(Path("cmp").glob("*.json")))
    text = str(report)
    assert "rmse" in text.lower()
    rmse = [v for k, v in _flatten(report) if k.lower().endswith("rmse_m") or k == "rmse"]
    assert rmse and max(abs(v) for v in rmse if v is not None) < 1e-3, rmse
    assert os.path.exists("ref_int16.tif")


def _flatten(obj, prefix=""):
    if isinstance(obj, dict):
        for key, value in obj.items():
            yield from _flatten(value, f"{key}")
    elif isinstance(obj, list):
        for value in obj:
            yield from _flatten(value, prefix)
    elif isinstance(obj, (int, float)):
        yield prefix, obj
