"""bench learn records the probes as a cell does: the probe reads the residual (true error minus
the compensation applied), with noise, quantised; the bag's total is that reading plus what was
applied. The totals are then not quantised (a hold fall-back would take quantised totals for
exact readings), and they are the very readings the replay's probe gave the running model."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from thermal_eval.learn.bench import recorded_probes
from thermal_eval.replay.summary import PROBE_RESOLUTION_UM
from thermal_eval.replay.virtual_experiment import ReplayProbe

COMPS = ["E_X0C", "E_C0C"]


def _result(seed: int = 4):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 40 * 300.0, 300.0)
    true = {c: np.cumsum(rng.normal(0.0, 0.3, t.size)) for c in COMPS}
    pred = {c: true[c] + rng.normal(0.0, 0.4, t.size) for c in COMPS}
    pred["E_X0C"][:3] = np.nan                            # no prediction yet: nothing applied
    return SimpleNamespace(time_s=t, components=COMPS, true=true, predicted=pred,
                           probe_times_s=list(t[[1, 5, 9, 17, 30]]))


def test_recorded_probes_are_the_replay_probes_readings_plus_what_was_applied():
    res, noise, seed = _result(), {"E_X0C": 0.25, "E_C0C": 1.2}, 7
    got = recorded_probes(res, None, noise, seed)
    probe = ReplayProbe(res.true, COMPS, noise, PROBE_RESOLUTION_UM, seed)
    for i, t in enumerate(res.probe_times_s):
        k = int(np.searchsorted(res.time_s, t))
        applied = {c: (0.0 if np.isnan(res.predicted[c][k]) else float(res.predicted[c][k])) for c in COMPS}
        probe.row = k
        read = probe(t, applied)
        for c in COMPS:
            assert got.values[c][i] == read[c] + applied[c]
    np.testing.assert_array_equal(got.time_s, res.probe_times_s)


def test_recorded_totals_are_not_quantised_where_compensation_was_applied():
    res = _result()
    got = recorded_probes(res, None, {"E_X0C": 0.25, "E_C0C": 1.2}, 3)
    steps = got.values["E_C0C"] / PROBE_RESOLUTION_UM
    assert np.max(np.abs(steps - np.round(steps))) > 0.05          # a total quantised would be 0
