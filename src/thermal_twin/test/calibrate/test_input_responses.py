"""A recorded boundary that the missing heat warms (a jacket's coolant return) can be
treated as a response while the missing input is estimated: held at its low level and not
fitted, while the recording given back keeps it as recorded."""
from __future__ import annotations

import numpy as np
import pytest

from thermal_twin.calibrate.input_estimation import InputEstimationError, as_responses
from thermal_twin.machine.schema import load_machine
from thermal_comp_common.recording_csv import Recording


def _rec():
    t = np.arange(0.0, 3600.0, 60.0)
    ret = 20.0 + 5.0 * (np.sin(t / 600.0) > 0)            # the return: 20 degC idle, 25 degC heated
    return Recording(t, {"t4_c": ret, "t11_c": np.full(t.size, 24.0), "t5_c": 30.0 + 0.001 * t})


def test_the_coolant_return_is_held_at_its_low_level_and_not_fitted():
    m = load_machine("fl-thermal-rig")
    rec = _rec()
    held, chans = as_responses(m, rec, ["t4_c", "t5_c", "t11_c"], ["coolant_degc"])
    assert chans == ["t5_c", "t11_c"]
    assert np.all(held.columns["t4_c"] == pytest.approx(20.0))
    assert np.array_equal(held.columns["t5_c"], rec.columns["t5_c"])
    assert np.ptp(rec.columns["t4_c"]) == pytest.approx(5.0)        # the caller's recording is untouched


def test_an_unknown_response_input_is_named():
    with pytest.raises(InputEstimationError, match="'coolant_flow'"):
        as_responses(load_machine("fl-thermal-rig"), _rec(), ["t4_c"], ["coolant_flow"])
