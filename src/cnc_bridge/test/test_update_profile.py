"""The bridge's per-prediction timing (cnc_bridge.update_profile)."""
import time

import pytest

from cnc_bridge.update_profile import COLUMNS, UpdateProfile, read_profile


def test_laps_add_up_per_phase_and_round_trip_through_the_csv(tmp_path):
    prof = UpdateProfile()
    prof.lap("transform")                 # before begin: nothing is timed
    assert prof.rows == []
    before = time.time()
    prof.begin(300_000_000_000)
    prof.lap("transform")
    prof.lap("audit")
    prof.lap("audit")                     # the same phase twice: added
    prof.note(round_trip_ms=1.25, round_trips=2)
    prof.end()
    prof.lap("publish")                   # after end: nothing is timed
    [row] = prof.rows
    assert before <= row["received_wall_s"] <= time.time()
    assert set(row) == {"stamp_ns", "received_wall_s", "transform_ms", "audit_ms", "round_trip_ms",
                        "round_trips"}
    assert all(row[k] >= 0.0 for k in ("transform_ms", "audit_ms"))
    prof.write_csv(tmp_path / "p" / "profile.csv")
    [back] = read_profile(tmp_path / "p" / "profile.csv")
    assert (tmp_path / "p" / "profile.csv").read_text().splitlines()[0] == ",".join(COLUMNS)
    assert back["stamp_ns"] == 300_000_000_000 and back["round_trips"] == 2
    assert back["audit_ms"] == pytest.approx(row["audit_ms"]) and "publish_ms" not in back
