"""learn's report carries what the mismatch finder's own functions locate: on a unit with a heat
source driven by C speed that the type's twin lacks, the residuals of the type's twin at the probe
instants stand out in a window while the spindle runs; the true twin's do not in the error channels."""
from __future__ import annotations

import numpy as np

from thermal_eval.learn.finder import finder_markdown, located
from thermal_eval.learn.structure import twin_outputs
from thermal_eval.learn.unit_fit import probe_recording
from thermal_eval.learn.probes import ProbeSet
from thermal_eval.learn.units import structural_unit
from thermal_twin.machine.schema import load_machine
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

COMPS = ["E_Y0C", "E_Z0T"]


def test_the_finder_locates_the_missing_source_in_the_spindle_running_regime():
    unit = structural_unit("extra_source", 15)              # an extra source on the cradle
    rec = simulate(unit.machine, make_timeline("nmv5000", "talc-178h-dry", hours=36.0, seed=15), seed=15).to_recording()
    idx = np.unique(np.searchsorted(rec.time_s, np.arange(0.0, 36 * 3600.0, 1800.0)))
    rng = np.random.default_rng(1)
    probes = ProbeSet(rec.time_s[idx], {c: rec.columns[c][idx] - rec.columns[c][0] + rng.normal(0, 0.25, idx.size)
                                         for c in COMPS}, {c: 0.25 for c in COMPS}, source="test")
    cell = probe_recording(rec, probes, COMPS)
    m = load_machine("nmv5000")
    rep = located(m, {"type": twin_outputs(m.to_dict(), cell), "truth": twin_outputs(unit.machine.to_dict(), cell)},
                  cell, COMPS, 36 * 3600.0)
    assert rep["instants"] == idx.size
    on_errors = [w for w in rep["type"]["windows"] if set(COMPS) & set(w["channels"])]
    assert on_errors and on_errors[0]["regime"].startswith("spindle running"), rep["type"]["windows"]
    assert max(abs(v["value"]) for c, v in on_errors[0]["effect"].items() if c in COMPS) > 1.0
    assert not [w for w in rep["truth"]["windows"] if set(COMPS) & set(w["channels"])], rep["truth"]["windows"]
    assert all(abs(e["effect"]) < 0.5 for e in rep["truth"]["regime_effects"] if e["channel"] in COMPS)
    md = "\n".join(finder_markdown(rep))
    assert "(spindle running" in md and "**truth**" in md


def test_too_few_probes_locate_nothing():
    m = load_machine("nmv5000")
    rec = simulate(m, make_timeline("nmv5000", "talc-178h-dry", hours=2.0, seed=1), seed=1).to_recording()
    probes = ProbeSet(rec.time_s[[3, 9]], {c: np.zeros(2) for c in COMPS}, {c: 0.25 for c in COMPS}, source="test")
    cell = probe_recording(rec, probes, COMPS)
    rep = located(m, {"type": twin_outputs(m.to_dict(), cell)}, cell, COMPS, 2 * 3600.0)
    assert "too few" in rep["note"] and "too few" in finder_markdown(rep)[-1]
