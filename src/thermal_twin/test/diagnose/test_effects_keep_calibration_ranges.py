"""An effect that renames a twin's parameters keeps the twin's own calibration ranges valid
(the fl-thermal-rig preset states ranges for its tilt channel's terms; a lag on that channel
moves each term to a lag node, and the augmented twin must still load)."""
from __future__ import annotations

from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.effects import time_lag_error


def test_a_lag_on_an_error_channel_moves_the_terms_calibration_ranges_to_the_lag_nodes():
    spec = load_machine("fl-thermal-rig").to_dict()
    before = spec["calibration"]["parameters"]["errors.ch5_um.terms.headstock"]
    augmented = load_machine(time_lag_error(spec, "ch5_um").apply(spec, [600.0])).to_dict()
    params = augmented["calibration"]["parameters"]
    assert "errors.ch5_um.terms.headstock" not in params
    assert params["errors.ch5_um.terms.mm_lag_ch5_um_headstock"] == before
    assert augmented["errors"]["ch5_um"]["terms"]["mm_lag_ch5_um_headstock"] == spec["errors"]["ch5_um"]["terms"]["headstock"]


def test_a_gain_set_beyond_the_twins_stated_range_leaves_a_valid_twin():
    from thermal_twin.diagnose.effects import elastic_gain
    spec = load_machine("fl-thermal-rig").to_dict()
    lo, hi = spec["calibration"]["parameters"]["errors.ch5_um.terms.base"]["bounds"]
    augmented = load_machine(elastic_gain(spec, "ch5_um", "base").apply(spec, [hi - lo + 1.0])).to_dict()
    assert augmented["errors"]["ch5_um"]["terms"]["base"] > hi
    assert "errors.ch5_um.terms.base" not in augmented["calibration"]["parameters"]
