"""Ephemeris coverage: lines outside the sampled ephemeris, or across a gap much longer
than its sampling, are masked with a note, never extrapolated in silence."""

import json
from pathlib import Path

import numpy as np
import pytest

from demtool.camera.info import camera_info
from demtool.errors import InputError
from demtool.sensors.coverage import GAP_FACTOR, Coverage, covered_lines, sampled_intervals
from demtool.sensors.isd import isd_from_sensor, read_isd, sensor_from_isd

DATA = Path(__file__).parent / "data"


def test_sampled_intervals_split_at_gaps_and_widen_by_one_spacing():
    times = np.concatenate([np.arange(0.0, 1.0, 0.1), np.arange(5.0, 6.0, 0.1)])
    spans = sampled_intervals(times)
    assert len(spans) == 2
    np.testing.assert_allclose(spans, [(-0.1, 1.0), (4.9, 6.0)], atol=1e-9)
    # a step of 8 spacings (as ALE's thinned ephemerides have) is not a gap
    assert len(sampled_intervals([0, 1, 2, 10, 11, 12])) == 1
    assert GAP_FACTOR > 8
    assert sampled_intervals([3.0]) == [(3.0, 3.0)]


def test_coverage_intersects_position_and_pointing():
    cov = Coverage.from_series({"instrument_position": np.arange(0.0, 10.0, 1.0),
                                "instrument_pointing": np.arange(4.0, 20.0, 1.0),
                                "body_rotation": np.array([0.0])})
    assert cov.intervals == [(3.0, 10.0)]
    np.testing.assert_array_equal(cov.covers([2.9, 3.0, 9.5, 10.5]), [False, True, True, False])


def _gapped_isd():
    """orbitalLineScan written on 25 nodes (0.0625 s), the nodes 2…22 removed from the
    position, pointing and body rotation: a 1.375 s gap, 22 spacings."""
    isd = isd_from_sensor(read_isd(DATA / "orbitalLineScan.json"))
    keep = [0, 1, 23, 24]
    for block in ("instrument_position", "sun_position"):
        b = isd[block]
        if len(b["ephemeris_times"]) == 25:
            for key in ("ephemeris_times", "positions", "velocities"):
                if key in b:
                    b[key] = [b[key][i] for i in keep]
    return isd, keep


def test_lines_across_a_gap_are_masked_with_a_note(caplog):
    full = read_isd(DATA / "orbitalLineScan.json")
    isd, _ = _gapped_isd()
    model = sensor_from_isd(isd, "gap.json")
    # rows 0-1 and 14-15 lie within one spacing of the samples; rows 2-13 in the gap
    assert covered_lines(model) == [(0, 1), (14, 15)]
    assert any("12 of 16 lines (75.0 %)" in n and "covered lines 0-1, 14-15" in n
               for n in model.notes)
    assert "gap.json" in caplog.text
    rows = np.arange(16) + 0.5
    ground = model.image_to_ground(rows, np.full(16, 8.0))
    masked = np.isnan(ground).any(axis=1)
    np.testing.assert_array_equal(masked, [False] * 2 + [True] * 12 + [False] * 2)
    # a ground point seen by a masked line has no image; a covered one projects back
    line, sample = model.ground_to_image(full.image_to_ground(rows, np.full(16, 8.0)))
    np.testing.assert_array_equal(np.isnan(line), masked)
    np.testing.assert_allclose(line[~masked], rows[~masked], atol=0.05)
    # camera reports the covered lines, and its footprint is the covered run only
    info = camera_info({"gap": model, "full": full}, {"gap": None, "full": None})
    gap_entry, full_entry = info["cameras"]
    assert gap_entry["covered_lines"] == [[0, 2], [14, 16]]
    assert gap_entry["footprint"]["area_km2"] < 0.3 * full_entry["footprint"]["area_km2"]


def test_no_covered_line_is_refused_in_one_line():
    isd = json.loads((DATA / "orbitalLineScan.json").read_text())
    # pointing samples that start after the last line: nothing to interpolate
    times = np.asarray(isd["instrument_pointing"]["ephemeris_times"])
    isd["instrument_pointing"]["ephemeris_times"] = (times + 5.0).tolist()
    with pytest.raises(InputError, match=r"late\.json: no image line lies within the "
                                         r"sampled ephemeris: 16 of 16 lines"):
        sensor_from_isd(isd, "late.json")
