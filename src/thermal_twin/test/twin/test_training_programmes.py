"""The designed prior-training programme of the nmv5000 type (thermal_twin.sim.scenarios,
``type-mwf-hall-phases``): MWF switches at every phase of the hall's day, short and long phases."""
import numpy as np
import pytest

from thermal_twin.sim.scenarios import make_timeline


@pytest.mark.parametrize("seed", [101, 106])
def test_mwf_switches_cover_the_hall_day_and_the_duration_range(seed):
    tl = make_timeline("nmv5000", "type-mwf-hall-phases", seed=seed)
    t, on = tl.time_s, tl.values["coolant_on"]
    switches = np.flatnonzero(np.diff(on) != 0) + 1
    hour_of_day = (8.0 + t[switches] / 3600.0) % 24.0          # hall_ambient starts at 08:00
    for q in range(4):                                          # switch-ons and -offs in every quarter
        sw_on = [h for h, i in zip(hour_of_day, switches) if on[i] == 1.0 and q * 6 <= h < (q + 1) * 6]
        sw_off = [h for h, i in zip(hour_of_day, switches) if on[i] == 0.0 and q * 6 <= h < (q + 1) * 6]
        assert sw_on and sw_off, f"seed {seed}: no MWF switch-on and -off between {q * 6} and {(q + 1) * 6} h"
    phases_h = np.diff(t[switches]) / 3600.0
    assert phases_h.min() >= 1.0 - 1e-6 and phases_h.max() <= 6.0 + 1e-6
    assert phases_h.min() < 1.6 and phases_h.max() > 5.4          # stratified: both ends occur
    amb = tl.values["ambient_degc"]
    assert np.ptp(amb) > 5.0                                        # the swinging hall (+-3 degC a day)


def test_training_programme_is_reproducible_and_seeded():
    a = make_timeline("nmv5000", "type-mwf-hall-phases", seed=3).values["coolant_on"]
    b = make_timeline("nmv5000", "type-mwf-hall-phases", seed=3).values["coolant_on"]
    c = make_timeline("nmv5000", "type-mwf-hall-phases", seed=4).values["coolant_on"]
    assert np.array_equal(a, b) and not np.array_equal(a, c)
