"""The identifiability check of item 6 fits a competitor only with the sign the finder's own
bounded fit and plausibility check allow (a new conduction path or a lag cannot be negated, a
gain can), and scores it on the held-out rows by what it leaves of the removal."""
from __future__ import annotations

import pathlib

import numpy as np

from thermal_eval.fl_thermal.identifiability import _left, _negative_ok
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.effects import conduction, elastic_gain, time_lag_sensor

TWIN = pathlib.Path(__file__).parents[3] / "thermal_twin" / "test" / "diagnose" / "mini_mill.yaml"


def test_only_the_words_that_may_change_sign_are_fitted_negative():
    spec = load_machine(TWIN).to_dict()
    assert not _negative_ok(conduction(spec, "spindle", "column"), np.array([2.0]))
    assert not _negative_ok(time_lag_sensor(spec, "head"), np.array([1800.0]))
    assert _negative_ok(elastic_gain(spec, "E_Z0T", "head"), np.array([1.0]))


def test_a_competitor_held_to_its_sign_cannot_explain_the_opposite_change():
    rng = np.random.default_rng(3)
    s_tr, s_h = rng.normal(size=60), rng.normal(size=30)
    comp = {"starts": [(s_tr, s_h)], "steps": [], "negative": [False]}
    d_tr, d_h = -2.0 * s_tr, -2.0 * s_h              # the removal is the opposite of its direction
    assert _left(d_tr, d_h, comp) == float(d_h @ d_h)          # leaves all of it
    assert _left(-d_tr, -d_h, comp) < 1e-20                    # the same sign: explained
    comp["negative"] = [True]
    assert _left(d_tr, d_h, comp) < 1e-20
