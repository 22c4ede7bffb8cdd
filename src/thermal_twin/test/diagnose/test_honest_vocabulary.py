"""Structure outside the vocabulary is answered ``unnamed``, the nearest word said as such.

A head sensor moved to the spindle body reads another node: no word of the vocabulary gains
beyond what the channel's noise model (white readings and a wandering level) explains, so the
words alone adopt nothing; the answer is ``unnamed`` with the formula on ``head_c`` and the lead
term's word only as the nearest.
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
    # the words alone adopt nothing: a bias's held-out gain is no more than the head channel's
    # wandering level explains (its residual is structured, so its noise carries a level)
    words_only = diagnose(SPEC, rec, unnamed=False).report
    assert words_only["answer"] == "none", words_only["answer"]
    rep = diagnose(SPEC, rec).report
    assert rep["answer"] == "unnamed" and rep["selected"] == "none", rep["answer"]
    (u,) = rep["unnamed"]
    # with no imitating word, the nearest is the lead term's: a coupling to the spindle temperature
    assert u["channel"] == "head_c" and u["nearest_vocabulary_word"] == "ambient_coupling", u
    assert "dspindle_c" in u["formula"], u["formula"]
    ch = rep["channels"]["head_c"]
    assert ch["holdout_rmse_after"] < 0.5 * ch["holdout_rmse_before"]
