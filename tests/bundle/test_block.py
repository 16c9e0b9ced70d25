"""`demtool bundle` on blocks without a target: a 12-view ring and a 6-frame strip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from demtool import io as dio
from demtool.cli import cli
from demtool.sensors.pinhole import cameras_from_arrays


def rotation_errors_deg(estimated: dict, truth: dict) -> np.ndarray:
    """Angle (degrees) between each estimated and true camera rotation after the one
    global rotation that best maps the model frame onto the world (gauge-free)."""
    names = sorted(estimated)
    # R_est_i ≈ R_true_i Q  ⇒  Q = argmax Σ tr(Q^T R_true_i^T R_est_i) (SVD projection)
    M = sum(truth[n].R.T @ estimated[n].R for n in names)
    u, _, vt = np.linalg.svd(M)
    Q = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    errors = []
    for n in names:
        delta = estimated[n].R @ Q.T @ truth[n].R.T
        errors.append(np.degrees(np.arccos(np.clip((np.trace(delta) - 1) / 2, -1, 1))))
    return np.asarray(errors)


def run(args: list[str], cwd: Path | None = None):
    runner = CliRunner()
    if cwd is None:
        return runner.invoke(cli, args)
    with runner.isolated_filesystem(temp_dir=cwd):
        return runner.invoke(cli, args)


@pytest.mark.slow
def test_ring_free_intrinsics_recovers_principal_point(ring_dir, tmp_path):
    """Issue 14: principal point 15 px off the centre in the truth → recovered within
    1 px, rotations within 0.05°; no distortion in the truth → none estimated."""
    out = tmp_path / "bundle.npz"
    images = sorted(str(p) for p in ring_dir.glob("view_*.tif"))
    result = run(["-q", "bundle", *images, "--out", str(out)])
    assert result.exit_code == 0, result.output
    truth = cameras_from_arrays(dio.read_npz(ring_dir / "cameras.npz", "cameras"))
    bundle = dio.read_npz(out, "bundle")
    cameras = cameras_from_arrays(bundle)
    assert sorted(cameras) == sorted(truth)
    summary = json.loads((tmp_path / "bundle.npz.json").read_text())["summary"]
    intrinsics = summary["intrinsics"]
    assert {"f", "cx", "cy"} <= set(intrinsics["refined"])
    assert "k2" not in intrinsics["refined"]  # no distortion in the truth: not significant
    true_K = truth["view_00"].K
    for camera in cameras.values():
        assert abs(camera.K[0, 2] - true_K[0, 2]) < 1.0
        assert abs(camera.K[1, 2] - true_K[1, 2]) < 1.0
        assert camera.K[0, 0] == pytest.approx(true_K[0, 0], rel=0.005)
    assert intrinsics["sigma"]["cx"] > 0 and intrinsics["sigma"]["f"] > 0
    # issue 27: the ring determines f (σ at the corners, on the relief, pose correlation)
    f_decision = intrinsics["decisions"]["f"]
    assert f_decision["status"] == "estimated" and f_decision["pose_correlation"] < 0.99
    assert f_decision["sigma"] < 0.005 * f_decision["value"]
    assert intrinsics["decisions"]["k2"]["status"] == "prior"
    np.testing.assert_array_less(np.abs(bundle["distortion"]), 1e-12)
    errors = rotation_errors_deg(cameras, truth)
    assert np.max(errors) < 0.05, errors
    rows = summary["images"]
    assert sorted(rows) == sorted(truth)
    assert all(r["observations"] > 200 and r["mean_residual_px"] < 0.5 for r in rows.values())


@pytest.mark.slow
def test_ring_known_intrinsics_register_in_one_pass(ring_dir, tmp_path):
    out = tmp_path / "bundle.npz"
    images = sorted(str(p) for p in ring_dir.glob("view_*.tif"))
    result = run(["-q", "bundle", *images, "--out", str(out),
                  "--cameras", str(ring_dir / "cameras.npz")])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "bundle.npz.json").read_text())["summary"]
    assert summary["registered_count"] == summary["image_count"] == 12
    assert {k: summary["mapping"][k] for k in ("mapping_passes", "retried", "free_fallback",
                                                "feature_passes")} == {
        "mapping_passes": 1, "retried": [], "free_fallback": False, "feature_passes": ["standard"]}
    assert summary["intrinsics"]["mode"] == "known" and summary["intrinsics"]["refined"] == []
    assert {d["status"] for d in summary["intrinsics"]["decisions"].values()} == {"given"}
    truth = cameras_from_arrays(dio.read_npz(ring_dir / "cameras.npz", "cameras"))
    cameras = cameras_from_arrays(dio.read_npz(out, "bundle"))
    for name, camera in cameras.items():
        np.testing.assert_allclose(camera.K, truth[name].K, atol=1e-9)
    assert np.max(rotation_errors_deg(cameras, truth)) < 0.05


@pytest.mark.slow
def test_strip_from_a_list_file_sequential(strip_dir, tmp_path):
    """A list file (paths relative to it), sequential matching, known intrinsics: all
    six frames in one pass; then free intrinsics register them all too."""
    listing = strip_dir.parent / "frames.txt"
    listing.write_text("# strip, west to east\n" + "".join(
        f"strip/view_{i:02d}.tif\n" for i in range(6)) + "\n")
    out = tmp_path / "bundle.npz"
    result = run(["-q", "bundle", "--images", str(listing), "--matcher", "sequential",
                  "--out", str(out), "--cameras", str(strip_dir / "cameras.npz")])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "bundle.npz.json").read_text())["summary"]
    assert summary["registered_count"] == 6 and summary["mapping"]["mapping_passes"] == 1
    truth = cameras_from_arrays(dio.read_npz(strip_dir / "cameras.npz", "cameras"))
    cameras = cameras_from_arrays(dio.read_npz(out, "bundle"))
    assert np.max(rotation_errors_deg(cameras, truth)) < 0.05
    # Collinear centres cannot fix a similarity; their spacing can: equal steps.
    centres = np.array([cameras[f"view_{i:02d}"].center for i in range(6)])
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    np.testing.assert_allclose(steps / steps.mean(), 1.0, atol=0.01)
    free = tmp_path / "free.npz"
    result = run(["-q", "bundle", "--images", str(listing), "--out", str(free)])
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "free.npz.json").read_text())["summary"]
    assert summary["registered_count"] == 6


def test_block_needs_overlap(tmp_path):
    """Images with no overlap: one line, exit 1, nothing written."""
    rng = np.random.default_rng(5)
    paths = []
    for name in ("noise_a", "noise_b", "noise_c"):
        path = tmp_path / f"{name}.tif"
        dio.write_raster(path, rng.normal(100, 20, (96, 96)))
        paths.append(str(path))
    out = tmp_path / "bundle.npz"
    result = run(["-q", "bundle", *paths, "--out", str(out)])
    assert result.exit_code == 1
    assert result.output.count("\n") == 1 and result.output.startswith("Error: ")
    assert "reconstruction failed" in result.output and "of 3 images registered" in result.output
    assert not out.exists() and not (tmp_path / "bundle.npz.json").exists()
