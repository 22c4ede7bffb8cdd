"""Physics outside the vocabulary is answered ``unnamed`` with its formula, never with a word.

Concealed cases on the mini_mill twin: a sensor that drifts linearly, a quadratic
thermo-elastic term; and a no-effect recording with coloured AR(1) sensor noise and dropped
rows, which must still answer ``none``.
"""
from __future__ import annotations

import pathlib

import pytest

from thermal_eval.diagnose.concealed import OutOfVocabulary as O, concealed_recording
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.diagnosis import diagnose

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()


def _unnamed(oov, seed):
    rec, _ = concealed_recording(SPEC, (), hours=48.0, step_s=300.0, seed=seed, oov=(oov,))
    return diagnose(SPEC, rec).report


def test_a_drifting_sensor_is_unnamed_with_a_time_term():
    rep = _unnamed(O("sensor_drift", "table", 0.01), 1)
    assert rep["answer"] == "unnamed" and rep["selected"] == "none", rep["selected"]
    (u,) = rep["unnamed"]
    assert u["channel"] == "table_c" and u["effect"] == "unnamed"
    term = next(t for t in u["terms"] if t["signal"] == "t_h")
    assert abs(term["coefficient"] - 0.01) < 0.002, u["formula"]
    assert u["holdout_improvement_pct"] > 50.0 and u["nearest_vocabulary_word"] == "sensor_bias"
    assert rep["channels"]["table_c"]["holdout_rmse_after"] < 0.5 * rep["channels"]["table_c"]["holdout_rmse_before"]


@pytest.mark.slow
def test_a_quadratic_thermo_elastic_term_is_unnamed():
    rep = _unnamed(O("quadratic_elastic", "E_Z0T/spindle", 0.05), 1)
    assert rep["answer"] == "unnamed", rep["selected"]
    (u,) = rep["unnamed"]
    term = next(t for t in u["terms"] if t["signal"] == "dspindle_c^2")
    assert abs(term["coefficient"] - 0.05) < 0.01, u["formula"]


def test_coloured_noise_and_dropped_rows_still_answer_none():
    rec, _ = concealed_recording(SPEC, (), hours=48.0, step_s=300.0, seed=4, ar1_sigma=0.03, drop_fraction=0.02)
    assert len(rec) < 577
    rep = diagnose(SPEC, rec).report
    assert rep["answer"] == "none" and rep["unnamed"] == [] and rep["selected"] == "none"
