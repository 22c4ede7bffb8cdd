"""TALC's input expressions (talc_config.input_signal): a signal, a difference, a product."""
import math

import pytest

from talc_model.talc.model import TalcModel
from talc_model.talc.config import input_signal

SIGNALS = {"ambient": 20.0, "ws_mwf": 27.5, "coolant_on": 1.0, "c_out": 21.0, "c_in": 19.5}


@pytest.mark.parametrize("name, value", [
    ("ambient", 20.0),
    ("c_out - c_in", 1.5),
    ("coolant_on * (ws_mwf - ambient)", 7.5),
    ("coolant_on * ws_mwf", 27.5),
    ("(c_out - c_in) * (ws_mwf - ambient)", 11.25),
])
def test_expressions(name, value):
    assert input_signal(name, SIGNALS) == pytest.approx(value)


def test_missing_signal_is_nan_and_a_bad_one_names_the_input():
    assert math.isnan(input_signal("coolant_on * (door - ambient)", SIGNALS))
    with pytest.raises(ValueError, match="coolant_on \\* ws_mwf"):
        input_signal("coolant_on * ws_mwf", {**SIGNALS, "ws_mwf": "hot"})


def test_product_input_is_a_delta_from_its_first_value_in_the_model():
    m = TalcModel({"component_names": ["E_X0C"], "angular_components": [],
                   "input_names": ["coolant_on * (ws_mwf - ambient)"]})
    m.update_inputs(0.0, {"ws_mwf": 21.0, "ambient": 20.0}, {"coolant_on": 0.0})
    m.update_inputs(300.0, {"ws_mwf": 27.0, "ambient": 20.0}, {"coolant_on": 1.0})
    assert m.input_last["coolant_on * (ws_mwf - ambient)"] == pytest.approx(7.0)
