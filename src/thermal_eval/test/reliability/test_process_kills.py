"""kill -9 of the model, the bridge and the twin in the middle of a lock-step run under the
launcher (restart enabled), compared with an undisturbed run; kill -9 of the recorder.

Stated tolerance (docs/reliability.md): every component's compensated P99 within 1 um
(um/m) of the undisturbed run -- the probe's repeatability (1 um, 2 sigma) and the CNC's
1 um resolution: a kill shifts which probe-noise draw lands on which cycle --, the
calibration phase ending within 0.25 h of it, no instant
without temperatures or a prediction, no audit-logged write outside the envelope.
"""
from __future__ import annotations

import pytest

from thermal_eval.reliability import fault_injection as fi
H = 3600.0
HOURS = 6.0            # programme hours; probing pauses stretch it to ~7.5 simulated hours
BRIDGE_KILL_H = 5.2  # last: its restart has a known effect on later figures (see the P99 test)
P99_TOLERANCE = 1.0    # um or um/m: OMP60 repeatability (2 sigma) = axis resolution


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("kills")
    base = fi.run_graph_faults(out / "undisturbed", HOURS, wall_timeout_s=300.0, p99_until_h=BRIDGE_KILL_H)
    hit = fi.run_graph_faults(out / "killed", HOURS, [fi.Kill("model", 4.0 * H), fi.Kill("machine_sim", 4.6 * H),
                                                     fi.Kill("bridge", BRIDGE_KILL_H * H)], wall_timeout_s=400.0,
                              p99_until_h=BRIDGE_KILL_H)
    return base, hit


@pytest.mark.slow
@pytest.mark.ros
def test_killed_nodes_restart_and_resume(runs):
    base, hit = runs
    assert all(k["killed"] and k["restarted"] for k in hit["kills"]), hit["kills"]
    assert hit["restarts"]["model"] == hit["restarts"]["bridge"] == hit["restarts"]["machine_sim"] == 1
    assert hit["model_resumed"] == 1 and hit["twin_resumed"] == 1   # from their saved state
    assert base["model_resumed"] == 0


@pytest.mark.slow
@pytest.mark.ros
def test_the_model_does_not_calibrate_again_and_loses_no_probing_cycle(runs):
    base, hit = runs
    assert not hit["back_to_calibration"] and hit["probing_counter_regressions"] == 0
    assert base["calibration_ended_h"] is not None and hit["calibration_ended_h"] is not None
    assert abs(hit["calibration_ended_h"] - base["calibration_ended_h"]) <= 0.25


@pytest.mark.slow
@pytest.mark.ros
def test_nothing_lost_nothing_unsafe(runs):
    base, hit = runs
    for r in (base, hit):
        assert r["unsafe_writes"] == [], r["unsafe_writes"]
        assert r["bag_damage"] is None
        assert r["lost"]["temperatures"] == 0 and r["lost"]["errors/predicted"] == 0, r["lost"]
        # defect 3 of docs/reliability.md, fixed: the recorder waits for the offsets of the instant a
        # restarted bridge answers (machine_sim re-sends it until the recorder has matched the bridge)
        assert r["lost"]["offsets"] == 0, r["missing_at_h"]
    # every instant's write is in the bridge's own fsync'ed audit log, also across the restart
    assert base["audit_missing_at_h"] == [] and hit["audit_missing_at_h"] == [], hit["audit_missing_at_h"]


@pytest.mark.slow
@pytest.mark.ros
def test_final_figures_within_tolerance_of_the_undisturbed_run(runs):
    """Compared up to the bridge's kill (the model's and the twin's kills lie before the cut);
    the whole run is compared by the next test, since the bridge adopts the offsets the CNC
    holds after a restart (defect 1 of docs/reliability.md, fixed)."""
    base, hit = runs
    a, b = base["p99_compensated_until"], hit["p99_compensated_until"]
    assert len(a) == 7
    diff = {c: round(b[c] - a[c], 3) for c in a}
    assert all(abs(v) <= P99_TOLERANCE for v in diff.values()), diff


@pytest.mark.slow
@pytest.mark.ros
def test_a_killed_recorder_leaves_a_readable_bag_up_to_the_crash(tmp_path, ros_domain_id):
    rec = fi.run_recorder_kill(tmp_path, int(ros_domain_id))
    assert rec["messages_readable"] > 10
    assert rec["damage"] is not None and "without MCAP footer" in rec["damage"]
    assert any(t.endswith("errors/ground_truth") for t in rec["topics"])
    # the restarted recorder keeps the crashed bag untouched and records on in bag.2
    assert rec["crashed_bag_unchanged"]
    assert "recording continues in" in rec["restart_output"], rec["restart_output"]
    assert rec["restart_exit_code"] == 0 and rec["restart_messages"] > 0


@pytest.mark.slow
@pytest.mark.ros
def test_whole_run_figures_within_tolerance_now_that_the_bridge_adopts_held_offsets(runs):
    """With the restarted bridge continuing from the offsets the CNC holds, the compensated
    P99 over the whole run stays within the tolerance of the undisturbed run too."""
    base, hit = runs
    a = {c: e["p99_compensated"] for c, e in base["summary"]["errors"].items()}
    b = {c: e["p99_compensated"] for c, e in hit["summary"]["errors"].items()}
    diff = {c: round(b[c] - a[c], 3) for c in a}
    print("whole-run P99 difference (killed - undisturbed):", diff)
    assert all(abs(v) <= P99_TOLERANCE for v in diff.values()), diff
