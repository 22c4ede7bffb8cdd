"""Structure outside the vocabulary is answered ``unnamed``, the imitating word said as the nearest.

A head sensor moved to the spindle body reads another node: a sensor bias is the best word
the vocabulary has (and is adopted when the out-of-vocabulary step is off), but it leaves a
structured residual on ``head_c``; the answer is ``unnamed`` with the formula on ``head_c`` and
``sensor_bias`` only as the nearest word.
"""
from __future__ import annotations

import copy
import pathlib

from thermal_eval.diagnose.concealed import concealed_recording
from thermal_twin.diagnose.diagnosis import diagnose
from thermal_twin.machine.schema import load_machine

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()


def test_a_moved_sensor_is_unnamed_and_the_imitating_word_is_only_the_nearest():
    true = copy.deepcopy(SPEC)
    true["sensors"]["head"]["of"] = "spindle"
    rec, _ = concealed_recording(true, (), hours=48.0, step_s=300.0, seed=1)
    words_only = diagnose(SPEC, rec, unnamed=False).report
    assert words_only["answer"] == "sensor_bias", words_only["answer"]
    rep = diagnose(SPEC, rec).report
    assert rep["answer"] == "unnamed" and rep["selected"] == "none", rep["answer"]
    (u,) = rep["unnamed"]
    assert u["channel"] == "head_c" and u["nearest_vocabulary_word"] == "sensor_bias", u
    assert "dspindle_c" in u["formula"], u["formula"]
    ch = rep["channels"]["head_c"]
    assert ch["holdout_rmse_after"] < 0.5 * ch["holdout_rmse_before"]
