"""bench/conformance.py (issue 41): its measurements on files with known answers, its table,
and — where ``../shared/data`` exists — a quick subset of the real corpus."""

from pathlib import Path

import pytest

from tests.helpers.bench import load_bench

DATA = Path(__file__).parent / "data"
SHARED = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


@pytest.fixture(scope="module")
def conformance():
    return load_bench("conformance")


def test_usgscsm_fixtures_load_and_close(conformance):
    results = conformance.run([str(DATA / "orbitalFramer.json"),
                               str(DATA / "orbitalPushFrame.json")])
    assert [r.path.name for r in results] == ["orbitalFramer.json", "orbitalPushFrame.json"]
    for r in results:
        assert r.status == "ok", (r.path, r.reason)
        assert r.hit_fraction == 1.0
        assert r.round_trip_px <= conformance.TOLERANCE_PX
    framer = results[0]
    assert framer.kind == "frame" and framer.size == "16×16"
    # orbitalFramer looks straight down at (lon 0, lat 0) of its 10 m sphere.
    assert framer.centre == pytest.approx((0.0, 0.0), abs=1e-6)


def test_refused_and_crashing_files_are_reported(conformance, tmp_path):
    broken = tmp_path / "broken.json"
    broken.write_text('{"name_model": "USGS_ASTRO_SAR_SENSOR_MODEL"}')
    result = conformance.check_file(broken)
    assert result.status == "refused"
    assert "USGS_ASTRO_SAR_SENSOR_MODEL" in result.reason
    assert conformance.collect([str(tmp_path / "*.json")]) == [broken]


def test_table_is_grouped_and_skips_without_shared(conformance, monkeypatch, capsys):
    results = conformance.run([str(DATA / "orbitalFramer.json")])
    rows = conformance.rows(results)
    assert len(rows) == 1 and len(rows[0]) == len(conformance.COLUMNS)
    assert rows[0][2] == "ok"
    monkeypatch.setattr(conformance, "FOLDERS", (Path("/nonexistent/conformance"),))
    assert conformance.main([]) == 0
    assert "skipped" in capsys.readouterr().out


def test_shared_subset():
    """A few real files of the corpus (the whole corpus: ``python bench/conformance.py``)."""
    folder = SHARED / "conformance" / "ale" / "tests" / "pytests" / "data" / "isds"
    if not folder.is_dir():
        pytest.skip("../shared/data/conformance is absent")
    conformance = load_bench("conformance")
    names = ["mariner10_isd.json", "themisvis_isd.json", "c1638610_isd.json",
             "galileossi_isd.json", "cassis_isd.json", "hayabusaamica_isd.json"]
    paths = [str(folder / n) for n in names]
    # MOC-NA: its pointing starts 0.37 s after the last line; MGS turns steadily, so the
    # attitude is extrapolated (coverage.attitude_end_margins) and the image loads
    paths.append(str(SHARED / "sensors" / "ale" / "mgsmocna_isd.json"))
    for r in conformance.run(paths):
        assert r.status == "ok", (r.path.name, r.status, r.reason)
