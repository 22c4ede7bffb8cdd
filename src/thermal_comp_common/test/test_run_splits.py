"""Splits of a data set by run (the one grammar of ``evaluate`` and ``calibrate`` ``--runs-split``):
fractions in date order, leave one run out, by a metadata field, named runs; refusals in one line."""
from __future__ import annotations

import pytest

from thermal_comp_common.recording_sources import DatasetError, RunEntry, resolve_runs
from thermal_comp_common.run_splits import DEFAULT_RUN_SPLIT, run_splits


@pytest.fixture()
def folder(tmp_path):
    d = tmp_path / "runs"
    d.mkdir()
    for k in range(5):
        (d / f"day{k}.csv").write_text("time_s,z_um\n0,0\n")      # the split reads names, not rows
    return d


def test_run_splits(folder, tmp_path):
    runs = resolve_runs([str(folder)])
    (f,) = run_splits(runs)
    assert f.name == DEFAULT_RUN_SPLIT
    assert (f.train, f.validation, f.test) == ((0, 1, 2), (3,), (4,))
    assert [x.test for x in run_splits(runs, "loro")] == [(i,) for i in range(5)]
    (f,) = run_splits(runs, "test=day1,day3;validation=day0")
    assert (f.train, f.validation, f.test) == ((2, 4), (0,), (1, 3))
    assert f.held_out() == [("validation", 0), ("test", 1), ("test", 3)]
    c = tmp_path / "m.csv"
    c.write_text("path,unit\n" + "".join(f"runs/day{k}.csv,U{k % 2}\n" for k in range(5)))
    units = resolve_runs([str(c)])
    assert [(x.train, x.test) for x in run_splits(units, "by:unit")] == [((1, 3), (0, 2, 4)), ((0, 2, 4), (1, 3))]
    (f,) = run_splits(units, "by:unit=U1")
    assert f.test == (1, 3) and f.train == (0, 2, 4)
    for bad, words in (("by:unit=U9", "U9"), ("by:colour", "'colour'"), ("0.5,0.5", "fractions"),
                       ("test=nope", "'nope'"), ("1,0,0", "held-out")):
        with pytest.raises(DatasetError, match=words):
            run_splits(units, bad)
    with pytest.raises(DatasetError, match="at least two"):
        run_splits(units[:1])


def test_fractions_follow_the_dates_when_every_run_has_one():
    runs = [RunEntry(f"r{k}.csv", f"r{k}", date=d) for k, d in enumerate(["2026-01-03", "2026-01-01", "2026-01-02"])]
    (f,) = run_splits(runs, "0.67,0,0.33")
    assert (f.train, f.test) == ((1, 2), (0,))


@pytest.mark.parametrize("how, words", [
    ("by:unit=U1,U2", "leaves no training run"),
    ("test=a,b", "at least one training run"),
    ("by:unit", "needs two values"),
])
def test_a_split_that_leaves_no_training_run_is_one_line_naming_the_value(how, words):
    runs = [RunEntry("a.csv", "a", unit="U1"), RunEntry("b.csv", "b", unit="U2")]
    if how == "by:unit":
        runs = [RunEntry("a.csv", "a", unit="U1"), RunEntry("b.csv", "b", unit="U1")]
    with pytest.raises(DatasetError) as e:
        run_splits(runs, how)
    msg = str(e.value)
    assert words in msg and how.partition("=")[0] in msg and "\n" not in msg
