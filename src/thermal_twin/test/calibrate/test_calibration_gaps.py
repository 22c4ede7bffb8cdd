"""`thermal-comp calibrate` leaves out the readings diagnose leaves out: after a gap of dropped rows
hiding an input change whose unknown instant moves the twin by more than the noise. Regular grids
are untouched; the held-out figures score the same readings before and after; the report counts
them per channel."""
from __future__ import annotations

import json

import numpy as np
import pytest

from thermal_twin.calibrate.cli import main
from thermal_twin.calibrate.fit import calibrate, left_out_lines
from thermal_twin.calibrate.runs import calibrate_runs
from thermal_twin.diagnose.diagnosis import _compare
from thermal_twin.diagnose.fit import FitProblem
from thermal_comp_common.metrics import rmse
from thermal_comp_common.recording_csv import Recording, write_recording_csv
from moved_mini_mill import SECTION, TRUE, TWIN, moved_runs


def _dropped_at_switches(rec: Recording, gap: int = 2, every: int = 4) -> Recording:
    """``rec`` without ``gap`` rows from every ``every``-th spindle switch on (first and last row kept)."""
    speed = next(k for k in rec.columns if "rpm" in k)
    switches = np.flatnonzero(np.diff(rec.columns[speed]) != 0) + 1
    keep = np.ones(len(rec), bool)
    for s in switches[::every]:
        keep[s:s + gap] = False
    keep[0] = keep[-1] = True
    return Recording(rec.time_s[keep], {k: np.asarray(v)[keep] for k, v in rec.columns.items()}, source="dropped")


@pytest.fixture(scope="module")
def full():
    """24 h of the moved twin on a regular 300 s grid (programme seed 3, noise seed 0)."""
    return moved_runs(1, 24.0, 3)[0]


def _rel_error(res) -> float:
    est = {e.param.path: e.value for e in res.estimates}
    return float(np.sqrt(np.mean([(est[p] / v - 1.0) ** 2 for p, v in TRUE.items()])))


def test_regular_grid_is_bit_identical_with_and_without_the_rule(full):
    a = calibrate(TWIN, full, section=SECTION, max_nfev=8)
    b = calibrate(TWIN, full, section=SECTION, max_nfev=8, leave_out_gaps=False)
    assert a.left_out == {} and a.left_out_counts() == {}
    assert [e.value for e in a.estimates] == [e.value for e in b.estimates]
    assert a.channel_table() == b.channel_table()
    assert a.cost_after == b.cost_after


def test_dropped_rows_at_switches_are_left_out_and_the_fit_is_closer_to_the_truth(full):
    rec = _dropped_at_switches(full)
    with_rule = calibrate(TWIN, rec, section=SECTION, max_nfev=30)
    without = calibrate(TWIN, rec, section=SECTION, max_nfev=30, leave_out_gaps=False)
    assert without.left_out == {}
    assert with_rule.left_out, "no reading left out after gaps hiding spindle switches"
    # nothing is left out before the first gap: the rule acts only after a hidden change
    first_gap = int(np.argmax(np.diff(rec.time_s) > 1.5 * np.median(np.diff(rec.time_s))))
    assert not any(m[:first_gap + 1].any() for m in with_rule.left_out.values())
    assert _rel_error(with_rule) < _rel_error(without), (_rel_error(with_rule), _rel_error(without))


@pytest.mark.parametrize("lattice", [0.0, 0.2])
def test_calibrate_leaves_out_the_readings_diagnose_leaves_out(full, lattice):
    """Diagnose's own comparison (no clock offset) and calibrate leave out the same readings, also
    where the recorder quantises the temperatures more coarsely than the twin's sensors."""
    rec = _dropped_at_switches(full)
    if lattice:
        for c in rec.columns:
            if c.endswith("_c"):
                rec.columns[c] = np.round(np.asarray(rec.columns[c]) / lattice) * lattice
    res = calibrate(TWIN, rec, section=SECTION, max_nfev=2)
    cmp = _compare(TWIN, rec, 1 / 3, False, None, 0, clock_offset=False)
    shared = [c for c in cmp.channels if c in res.channels]
    assert len(shared) >= 5 and sum(int(m.sum()) for m in res.left_out.values()) > 0
    if lattice:     # the lattice raises the noise the rule compares with above the readings' own
        spread = FitProblem(rec, shared, res.n_train).sigma
        assert any(res.sigma[c] > 2.0 * spread[c] for c in shared)
    for j, c in enumerate(cmp.channels):
        if c in shared:
            assert res.sigma[c] == cmp.problem.sigma[c], c
            left = ~cmp.problem._valid[j] & np.isfinite(np.asarray(rec.columns[c], dtype=float))
            assert np.array_equal(left, res.left_out.get(c, np.zeros(len(rec), bool))), c


def test_held_out_figures_score_the_same_readings_before_and_after(full):
    rec = _dropped_at_switches(full)
    res = calibrate(TWIN, rec, section=SECTION, max_nfev=8)
    k = res.n_train
    counts = res.left_out_counts()
    assert sum(v["holdout"] for v in counts.values()) > 0
    for c, row in res.channel_table().items():
        m = np.asarray(rec.columns[c], dtype=float).copy()
        if c in res.left_out:
            m[res.left_out[c]] = np.nan
        for when in ("before", "after"):
            y = getattr(res, when)[c]
            assert row[f"holdout_rmse_{when}"] == pytest.approx(rmse(m[k:], y[k:]), nan_ok=True)
            assert row[f"train_rmse_{when}"] == pytest.approx(rmse(m[:k], y[:k]), nan_ok=True)
    for c, v in counts.items():
        assert v["train"] + v["holdout"] == int(res.left_out[c].sum())
        assert v["holdout"] == int(res.left_out[c][k:].sum())


def test_several_runs_leave_out_the_same_readings_in_every_run(full):
    runs = [_dropped_at_switches(full), *moved_runs(1, 12.0, 11)]
    rc = calibrate_runs(TWIN, runs, ["gappy", "regular"], holdout=1, section=SECTION, max_nfev=4)
    n0 = len(runs[0])
    assert rc.result.left_out
    assert not any(m[n0:].any() for m in rc.result.left_out.values())      # the regular run: nothing
    single = calibrate(TWIN, runs[0], section=SECTION, max_nfev=4, sigma=rc.result.sigma)
    for c, m in rc.result.left_out.items():
        assert np.array_equal(m[:n0], single.left_out.get(c, np.zeros(n0, bool))), c
        assert rc.runs[0]["channels"][c]["n"] == int(np.count_nonzero(np.isfinite(runs[0].columns[c]) & ~m[:n0]))


def test_report_says_how_many_readings_were_left_out_and_why(full, tmp_path, capsys):
    rec = _dropped_at_switches(full)
    path = tmp_path / "gappy.csv"
    write_recording_csv(path, rec.time_s, rec.columns)
    bounds = tmp_path / "bounds.yaml"
    bounds.write_text(json.dumps({"calibration": SECTION}))
    out = tmp_path / "cal"
    assert main(["--twin", str(TWIN), "--recording", str(path), "--out", str(out), "--quiet",
                 "--bounds", str(bounds), "--max-nfev", "4"]) == 0
    printed = capsys.readouterr().out
    rep = json.loads((out / "report.json").read_text())
    assert rep["left_out"]
    md = (out / "report.md").read_text()
    for line in left_out_lines(rep["left_out"]):
        assert f"- {line}" in md and f"left out: {line}" in printed
    c, v = next(iter(rep["left_out"].items()))
    assert f"{c}: {v['train'] + v['holdout']} readings left out ({v['train']} training, {v['holdout']} held-out)" in md
