"""evaluate's opt-in rows that re-fit the ridge at each probing (talc_model.open_loop.probe_refit)."""
from __future__ import annotations

import numpy as np

from synthetic_recording import synthetic
from talc_model.open_loop.probe_refit import WEIGHTS
from thermal_comp_common.recording_csv import Recording
from thermal_eval.evaluate.run import WALK_FORWARD_PHASES, available_models, evaluate
from thermal_eval.evaluate.spec import evaluation_data


def test_the_refit_rows_are_opt_in_and_choose_on_the_training_rows():
    cols = synthetic()
    d = evaluation_data(Recording(cols.pop("time_s"), cols), {})
    names = ["lagged_ridge_refit", "lowpass_ridge_refit"]
    assert not set(names) & {m.name for m in available_models(d)}
    res = evaluate(d, models=available_models(d, names), show_progress=False)
    held = dict(d.displacement_um)
    for name in names:
        for ch in d.channels:
            info = res.figures["open_loop"][name]["channels"][ch]["probe_refit"]
            assert info["weight"] in WEIGHTS and info["walk_forward_phases"] == WALK_FORWARD_PHASES
            assert "mae_test_um" in res.figures["adaptive"][name]["channels"][ch]
    # the open loop of the low-pass row is the lowpass_ridge baseline's
    for ch in d.channels:
        assert np.allclose(res.open_loop["lowpass_ridge_refit"][ch], res.open_loop["lowpass_ridge"][ch])
    for ch in d.channels:    # poison the held-out rows: the choice does not change
        d.displacement_um[ch] = np.where(np.arange(len(d)) < d.split.n_train, held[ch], 1e6)
    again = evaluate(d, models=available_models(d, names), show_progress=False)
    for name in names:
        for ch in d.channels:
            assert (res.figures["open_loop"][name]["channels"][ch]["probe_refit"]
                    == again.figures["open_loop"][name]["channels"][ch]["probe_refit"])
