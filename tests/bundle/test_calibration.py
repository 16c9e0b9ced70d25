"""Self-calibration asks the block what it determines (issue 27).

Fast tests of :mod:`demtool.bundle.determinability` on analytic blocks (points seen
through true pinholes, no rendering), then the self-calibration through the CLI on the
rendered 12-view ring and 6-frame strip of ``conftest.py``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.bundle.determinability import intrinsic_determinability
from demtool.cli import cli
from demtool.sensors.pinhole import cameras_from_arrays

FOCAL_PX = 600.0
SIZE = 800


def _look_at(centre, target):
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0] if abs(z[1]) < 0.9 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])  # rows: world → camera


def _block(centres, targets, relief_m, seed=0):
    """Observations of 3000 ground points (heights ±relief_m) in pinholes at ``centres``
    looking at ``targets``: the inputs of intrinsic_determinability."""
    rng = np.random.default_rng(seed)
    xyz = np.column_stack([rng.uniform(-500, 500, 3000), rng.uniform(-500, 500, 3000),
                           rng.uniform(-relief_m, relief_m, 3000)])
    rotations = np.array([_look_at(c, t) for c, t in zip(centres, targets, strict=True)])
    image, point, cam = [], [], []
    for i, (r, c) in enumerate(zip(rotations, centres, strict=True)):
        p = (xyz - c) @ r.T
        u = FOCAL_PX * p[:, 0] / p[:, 2]
        v = FOCAL_PX * p[:, 1] / p[:, 2]
        seen = (p[:, 2] > 0) & (np.abs(u) < SIZE / 2) & (np.abs(v) < SIZE / 2)
        image.append(np.full(seen.sum(), i))
        point.append(np.flatnonzero(seen))
        cam.append(p[seen])
    image, point, cam = np.concatenate(image), np.concatenate(point), np.concatenate(cam)
    _, point = np.unique(point, return_inverse=True)
    return cam, image, point, rotations, np.asarray(centres, dtype=np.float64)


def test_ring_determines_the_focal_length():
    """Eight views converging from 45° off nadir: f to 0.05 % at 0.2 px ties, and the
    poses do not absorb it."""
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    centres = np.column_stack([1000 * np.cos(angles), 1000 * np.sin(angles),
                               np.full(8, 1000.0)])
    det = intrinsic_determinability(*_block(centres, np.zeros((8, 3)), 50.0),
                                    focal_px=FOCAL_PX, free=("f", "cx", "cy"))
    sigma_f = det.row("f", sigma0=0.2)["sigma"]
    assert sigma_f < 0.0005 * FOCAL_PX
    assert det.row("f")["pose_correlation"] < 0.99
    assert det.row("cx", sigma0=0.2)["sigma"] < 3.0


def test_flat_strip_does_not_determine_the_focal_length():
    """Six frames in a line 1 km over ground flat to ±5 m.  Exactly nadir, a change of f
    is matched by the points' depths (σ_f ≫ f); tilted by ~3° at random, σ_f falls to
    under 1 % of f, but the poses absorb it (correlation > 0.999: the tilts and flying
    heights trade for it), as they do on the Apollo frames of issue 27."""
    centres = np.column_stack([np.linspace(-400, 400, 6), np.zeros(6), np.full(6, 1000.0)])
    nadir = centres * [1, 1, 0]
    det = intrinsic_determinability(*_block(centres, nadir, 5.0), focal_px=FOCAL_PX,
                                    free=("f",))
    assert det.row("f", sigma0=0.2)["sigma"] > 0.1 * FOCAL_PX
    tilted = nadir + np.random.default_rng(1).normal(0, 50, (6, 3)) * [1, 1, 0]
    det = intrinsic_determinability(*_block(centres, tilted, 5.0), focal_px=FOCAL_PX,
                                    free=("f",))
    row = det.row("f", sigma0=0.2)
    assert row["sigma"] < 0.01 * FOCAL_PX
    assert row["pose_correlation"] > 0.999
    assert row["sigma_poses_fixed"] < 0.05 * row["sigma"]


def run(args):
    return CliRunner().invoke(cli, args)


@pytest.mark.slow
def test_flat_strip_keeps_the_focal_length_at_the_prior(strip_dir, tmp_path):
    """Free intrinsics on the strip: f is not determined, so it stays at 1.2 × the image
    size with one warning naming what to give; the sidecar records every decision.
    With --focal-mm/--pixel-mm the given focal length is used as it is."""
    images = [str(strip_dir / f"view_{i:02d}.tif") for i in range(6)]
    out = tmp_path / "free.npz"
    result = run(["bundle", *images, "--matcher", "sequential", "--out", str(out)])
    assert result.exit_code == 0, result.output
    warnings = [line for line in result.stderr.splitlines() if "focal length" in line]
    assert len(warnings) == 1, warnings
    assert "does not determine the focal length" in warnings[0]
    assert "--focal-mm" in warnings[0] and "--pixel-mm" in warnings[0]
    intrinsics = json.loads(out.with_suffix(".npz.json").read_text())["summary"]["intrinsics"]
    assert "f" not in intrinsics["refined"]
    assert intrinsics["decisions"]["f"]["status"] == "prior"
    assert intrinsics["decisions"]["f"]["value"] == pytest.approx(1.2 * 256)
    cameras = cameras_from_arrays(dio.read_npz(out, "bundle"))
    assert all(c.K[0, 0] == pytest.approx(1.2 * 256) for c in cameras.values())

    known = tmp_path / "known.npz"
    truth = cameras_from_arrays(dio.read_npz(strip_dir / "cameras.npz", "cameras"))
    focal = truth["view_00"].K[0, 0]
    result = run(["-q", "bundle", *images, "--matcher", "sequential", "--out", str(known),
                  "--focal-mm", str(focal * 0.005), "--pixel-mm", "0.005"])
    assert result.exit_code == 0, result.output
    summary = json.loads(known.with_suffix(".npz.json").read_text())["summary"]
    assert summary["intrinsics"]["decisions"]["f"]["status"] == "given"
    cameras = cameras_from_arrays(dio.read_npz(known, "bundle"))
    assert all(c.K[0, 0] == pytest.approx(focal) for c in cameras.values())


@pytest.mark.parametrize("args, option", [(["--focal-mm", "76"], "--focal-mm"),
                                          (["--pixel-mm", "0.1"], "--pixel-mm")])
def test_focal_mm_and_pixel_mm_go_together(tmp_path, args, option):
    images = []
    for name in ("a", "b"):
        path = tmp_path / f"{name}.tif"
        dio.write_raster(path, np.zeros((32, 32), np.float32))
        images.append(str(path))
    out = tmp_path / "bundle.npz"
    result = run(["-q", "bundle", *images, "--out", str(out), *args])
    assert result.exit_code == 1
    assert result.output.count("\n") == 1 and result.output.startswith("Error: ")
    assert option in result.output and "ratio" in result.output
    assert not out.exists()
