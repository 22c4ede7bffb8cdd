"""``thermal-comp bench faults`` survives its own cases: a case that raises is one failed row with
its reason and the other rows are kept; the integrity rows (tampered prior and state, second
launch, full disk) run in seconds and survive."""
from __future__ import annotations

import pytest

from thermal_eval.bench import faults
from thermal_eval.reliability import hang_and_file_faults, integrity_faults
from thermal_eval.reliability.fault_rows import guarded
from thermal_eval.reliability.link_faults import LinkFaultResult


def test_a_link_case_that_raises_is_one_failed_row_and_the_others_are_kept(monkeypatch):
    def run_link_fault(fault, port):
        if fault == "stalled":
            raise TimeoutError("CNC emulator on opc.tcp://127.0.0.1:1/x: not listening within 20 s")
        return LinkFaultResult(fault, True, 0, [], "CNC holds X=8.000 um")
    monkeypatch.setattr(faults.fi, "run_link_fault", run_link_fault)
    rows = faults.link_rows()
    assert [r["fault"] for r in rows] == ["server restart", "server reset", "stalled", "wrong credentials",
                                          "rejected write", "bridge restart"]
    failed = [r for r in rows if not r["survived"]]
    assert [r["fault"] for r in failed] == ["stalled"]
    assert failed[0]["detail"].startswith("did not run: TimeoutError: CNC emulator on")
    assert "not listening within 20 s" in failed[0]["why"]
    assert all(r["survived"] and r["injected"] == 1 for r in rows if r["fault"] != "stalled")


def test_a_module_case_that_raises_is_one_failed_row(monkeypatch, tmp_path):
    def broken(*a):
        raise RuntimeError("machine_sim did not start")
    monkeypatch.setattr(hang_and_file_faults, "lockstep_absent_row", broken)
    monkeypatch.setattr(hang_and_file_faults, "recorder_lockstep_kill_row",
                        lambda out, env: hang_and_file_faults._row("recorder", "kill", True, "ok"))
    monkeypatch.setattr(hang_and_file_faults, "bad_file_rows",
                        lambda out, env: [hang_and_file_faults._row("bad file", f"case {i}", True, "ok")
                                          for i in range(3)])
    rows = hang_and_file_faults.rows(tmp_path, 0)
    assert len(rows) == 5 and [r["survived"] for r in rows] == [False, True, True, True, True]
    assert rows[0]["fault"] == "participant never joins"
    assert rows[0]["detail"] == "did not run: RuntimeError: machine_sim did not start"


def test_guarded_keeps_rows_and_figures_of_cases_that_work():
    figures = {}
    ok = faults._rows_and_figures("sensor", "sensors", lambda: ([{"fault": "a"}], {"p99": 1.0}), figures)
    assert ok == [{"fault": "a"}] and figures == {"sensors": {"p99": 1.0}}
    bad = faults._rows_and_figures("process", "processes", lambda: 1 / 0, figures)
    assert len(bad) == 1 and not bad[0]["survived"] and "ZeroDivisionError" in bad[0]["detail"]
    assert "processes" not in figures
    assert guarded("x", "y", lambda: {"fault": "one"}) == [{"fault": "one"}]


def test_the_integrity_rows_run_and_survive(tmp_path):
    rows = integrity_faults.rows(tmp_path)
    assert [r["fault"] for r in rows] == ["prior: ARX x1000, hash re-computed", "prior: one byte flipped",
                                          "model state: edited / other inputs", "second launch of a running cell",
                                          "disk full while recording (ENOSPC)"]
    assert all(r["survived"] for r in rows), [r["detail"] for r in rows if not r["survived"]]
    assert sum(r["data_lost"] + r["unsafe_writes"] for r in rows) == 0
    assert "not inside the unit circle" in rows[0]["detail"]
    assert "sha256" in rows[1]["detail"]


def test_the_full_disk_row_fails_when_flushed_messages_are_lost(tmp_path, monkeypatch):
    # a writer that drops what was flushed: the row must count it as lost, not survived
    real_read = integrity_faults.read_bag

    def read_without_the_first(path):
        contents = real_read(path)
        del contents.messages[:5]
        return contents
    monkeypatch.setattr(integrity_faults, "read_bag", read_without_the_first)
    row = integrity_faults.full_disk_row(tmp_path)
    assert not row["survived"] and row["data_lost"] >= 1


@pytest.mark.ros
def test_the_forged_stamp_rows_run_and_survive(ros_domain_id):
    from thermal_eval.reliability import stamp_faults
    rows = stamp_faults.rows(ros_domain_id)
    assert [r["fault"] for r in rows] == ["temperatures stamped 1e7 s ahead -> model",
                                          "prediction stamped 1e7 s ahead -> bridge"]
    assert all(r["survived"] for r in rows), [r["detail"] for r in rows]
    assert sum(r["data_lost"] + r["unsafe_writes"] for r in rows) == 0
    assert rows[0]["detail"] == "model clock 18000 s after it; state saved at 18300 s; 1 refused"


def test_the_bridge_stamp_row_fails_when_a_forged_prediction_gets_through(monkeypatch):
    # a guard that accepts every stamp: the forged -30 um is followed, the watchdog never fires
    from thermal_eval.reliability import stamp_faults
    monkeypatch.setattr(stamp_faults.StampGuard, "_verdict", lambda self, s, c: (None, ""))
    r = stamp_faults.bridge_case()
    assert r["refused"] == 0 and not any(r["watchdog"])
    row = stamp_faults.bridge_row()
    assert not row["survived"]


def test_the_bridge_follows_honest_predictions_at_the_rate_limit_after_a_forged_one():
    from thermal_eval.reliability import stamp_faults
    r = stamp_faults.bridge_case(honest_after=6, silent_steps=4)
    assert r["applied_um"][:10] == [0.0, 2.5, 5.0, 5.0, 7.5, 10.0, 10.0, 10.0, 10.0, 10.0]
    assert r["watchdog"] == [False] * 10 + [True] * 4 and r["refused"] == 5 and r["violations"] == []
