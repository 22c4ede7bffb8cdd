"""build_talc_prior with an input that never varies in the training part (the MWF flag when only
dry programmes train): the order search leaves it out instead of every candidate failing."""
import math

import numpy as np

from talc_model.prior.talc import build_talc_prior
from thermal_comp_common.recording_csv import Recording

CFG = {"component_names": ["E_X0C"], "angular_components": [], "input_names": ["amb", "flag"],
       "na_max": 1, "nb_max": 2, "nb_max_final": 2}


def _plant(seed: int, wet: bool, hours: float = 48.0) -> Recording:
    """E = first-order lag (tau 3 h) of 3 x ambient delta + 4 x flag (on/off every 5 h if wet)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 300.0)
    amb = 20 + sum(rng.uniform(0.5, 2) * np.sin(2 * np.pi * t / (rng.uniform(4, 30) * 3600) + rng.uniform(0, 6))
                   for _ in range(3))
    amb -= amb[0] - 20
    flag = ((t // (5 * 3600.0)) % 2).astype(float) if wet else np.zeros_like(t)
    a = math.exp(-300.0 / (3 * 3600.0))
    e = np.zeros_like(t)
    for k in range(1, t.size):
        e[k] = a * e[k - 1] + (1 - a) * (3.0 * (amb[k - 1] - 20) + 4.0 * flag[k - 1])
    return Recording(t, {"amb_c": amb, "flag": flag, "E_X0C": e}, source="synthetic")


def test_an_input_constant_in_training_enters_the_refit_with_one_lag():
    prior = build_talc_prior([_plant(1, False), _plant(2, False), _plant(3, True)], CFG, nb_max=2)
    m = prior["talc_state"]["models"]["E_X0C"]
    assert m["orders"]["nb"][1] == 1 and m["orders"]["nb"][0] >= 1
    theta = np.asarray(m["theta"])
    a1, b_flag = theta[0], theta[-1]
    assert abs(b_flag / (1 + a1) - 4.0) < 0.2        # the wet recording's flag gain, recovered


def test_an_input_that_never_varies_stays_out():
    prior = build_talc_prior([_plant(1, False), _plant(2, False)], CFG, nb_max=2)
    assert prior["talc_state"]["models"]["E_X0C"]["orders"]["nb"][1] == 0
