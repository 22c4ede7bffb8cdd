"""thermal-comp sweep: the Table 6.1 grid, the resumable parallel runner, the best-set choice."""
from __future__ import annotations

import json
import math
import pathlib

import pytest

from thermal_eval.sweep import grid as sweep
from thermal_eval.sweep.grid import (SweepError, SweepPoint, SweepRun, best_under_constraint, max_q_prod_front,
                              parse_grid_subset, read_results, run_sweep, select_points, table_6_1_grid)
from thermal_eval.sweep.cli import main as sweep_main
from talc_model.talc.model import TalcConfig


def test_grid_has_the_thesis_count_of_valid_distinct_combinations():
    grid = table_6_1_grid()
    assert len(grid) == sweep.THESIS_COMBINATIONS_PER_LOAD_CASE == 2191
    assert len({p.key() for p in grid}) == len(grid)
    full = 1
    for values in sweep.TABLE_6_1.values():
        full *= len(values)
    assert full == 44590                         # the thesis's full factorial
    for p in grid:
        for name, value in p.config().items():
            if name != "update_interval_h":
                assert value in sweep.TABLE_6_1[name], (name, value)
        TalcConfig.from_mapping(p.config())       # every combination is a valid configuration
    assert sum(math.isinf(p.post_cp_interval_h) for p in grid) == len(sweep.CP_LENGTH_H)


def test_grid_subset_and_limit():
    grid = table_6_1_grid()
    sub = select_points(grid, parse_grid_subset("cp_length_h=8.5;post_cp_interval_h=2,inf"))
    assert len(sub) == 6 * 4 + 1
    twice = select_points(grid, parse_grid_subset("cp_length_h=12;update_interval_h=8,inf"))
    assert len(twice) == 2 * 313 and {p.update_interval_h for p in twice} == {8.0, math.inf}
    lim = select_points(grid, None, 5)
    assert len(lim) == 5 and lim[0] == grid[0] and lim[-1] == grid[-1]
    with pytest.raises(SweepError, match="cp_lenght_h"):
        parse_grid_subset("cp_lenght_h=8.5")
    with pytest.raises(SweepError, match="post_cp_interval_h.*'two'"):
        parse_grid_subset("post_cp_interval_h=two")


def _row(key, p99_lin, q):
    return {"key": key, "p99_lin_um": p99_lin, "q_prod_pct": q, "p99_ang_um_per_m": 1.0}


def test_best_respects_the_q_prod_constraint():
    rows = [_row("a", 2.0, 94.99), _row("b", 4.0, 96.0), _row("c", 3.5, 95.0), _row("d", 3.5, 97.0),
            _row("e", math.nan, 99.0), _row("f", 6.0, 99.5)]
    best = best_under_constraint(rows, 95.0)
    assert best["key"] == "d"                    # lowest P99_lin at Q_prod >= 95; tie -> higher Q_prod
    assert best_under_constraint(rows, 99.0)["key"] == "f"
    assert best_under_constraint(rows[:1], 95.0) is None
    assert max_q_prod_front(rows, [1.0, 3.0, 3.6, 10.0])[1:] == [94.99, 97.0, 99.5]
    assert math.isnan(max_q_prod_front(rows, [1.0])[0])


def test_sweep_cli_three_combinations_two_jobs_then_resumes(short_csv, tmp_path):
    out = tmp_path / "sweep"
    argv = [str(short_csv), "--out", str(out), "--jobs", "2", "--limit", "3",
            "--grid-subset", "cp_length_h=8.5;post_cp_interval_h=1,3,inf", "--no-progress"]
    assert sweep_main(argv) == 0
    lines = (out / "results.jsonl").read_text().splitlines()
    assert len(lines) == 3
    rows = [json.loads(x) for x in lines]
    for r in rows:
        for k in ("p99_lin_um", "p99_ang_um_per_m", "q_prod_pct", "probing_cycles", "no_good_phases", "seconds"):
            assert k in r
        assert set(r["p99"]) == set(r["rms"]) and len(r["p99"]) == 7
    table = (out / "table.csv").read_text().splitlines()
    assert len(table) == 4 and table[0].startswith("cp_length_h,post_cp_interval_h")
    assert (out / "p99_vs_qprod.png").stat().st_size > 0 and (out / "qprod_vs_p99_limit.png").stat().st_size > 0
    summary = json.loads((out / "best.json").read_text())
    assert summary["computed"] == 3 and summary["combinations"] == 3
    expected = best_under_constraint([{**r, "p99_lin_um": float(r["p99_lin_um"]), "q_prod_pct": float(r["q_prod_pct"])}
                                      for r in rows])
    assert (summary["best"] or {}).get("key") == (expected or {}).get("key")
    # probing every hour after the CP costs more productivity than every 3 h or never
    q = {r["params"]["post_cp_interval_h"]: r["q_prod_pct"] for r in rows}
    assert q["inf"] >= q[3.0] > q[1.0]

    # rerun: nothing recomputed, nothing lost
    before = (out / "results.jsonl").read_text()
    assert sweep_main(argv) == 0
    assert json.loads((out / "best.json").read_text())["computed"] == 0
    assert (out / "results.jsonl").read_text() == before


def test_interrupted_results_file_recomputes_only_the_cut_line(short_csv, tmp_path):
    from thermal_eval.replay.summary import load_replay_recording
    rec = load_replay_recording(short_csv)
    run = SweepRun("talc", {"input_names": list(sweep.TALC_INPUTS)}, 0.25, 1.2, 0.25, 0, "test")
    pts = [SweepPoint(8.5, math.inf, 10.0, 12.0, 24.0), SweepPoint(8.5, 24.0, 30.0, 6.0, 24.0)]
    path = tmp_path / "results.jsonl"
    calls = []

    def fake(recording, run_, point):             # the runner's bookkeeping, not the replay, is tested
        calls.append(point.key())
        return {"key": point.key(), "run": run_.fingerprint(), "params": point.config(), "p99_lin_um": 1.0,
                "q_prod_pct": 99.0, "p99_ang_um_per_m": 1.0, "p99": {}, "rms": {}, "seconds": 0.0}
    run_sweep(rec, run, pts, path, jobs=1, progress=False, evaluate=fake)
    assert calls == [p.key() for p in pts]
    text = path.read_text()
    path.write_text(text[: len(text) - 20])       # the second line cut off mid-write
    calls.clear()
    res = run_sweep(rec, run, pts, path, jobs=1, progress=False, evaluate=fake)
    assert calls == [pts[1].key()] and res["skipped"] == 1 and res["computed"] == 1
    assert any("incomplete line" in w for w in res["warnings"])
    rows, warnings = read_results(path, run.fingerprint())
    assert [r["key"] for r in rows] == [p.key() for p in pts] and not warnings
    other = SweepRun("talc", {"input_names": ["ambient"]}, 0.25, 1.2, 0.25, 0, "test")
    with pytest.raises(SweepError, match=r"results\.jsonl:1: result of another run"):
        run_sweep(rec, other, pts, path, jobs=1, progress=False, evaluate=fake)
    assert len(path.read_text().splitlines()) == 2     # the refused run left the file untouched
