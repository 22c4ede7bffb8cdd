"""The synthetic C-axis plant used by the refit benchmark."""
import numpy as np

from thermal_twin.sim.synthetic_plant import TABLE_6_5_P99, make_plant


def test_plant_is_reproducible_and_scaled_to_table_6_5():
    a = make_plant(hours=24.0, step_s=300.0, seed=4)
    b = make_plant(hours=24.0, step_s=300.0, seed=4)
    c = make_plant(hours=24.0, step_s=300.0, seed=5)
    for name, e in a.errors.items():
        np.testing.assert_array_equal(e, b.errors[name])
        assert abs(np.percentile(np.abs(e), 99, method="hazen") - TABLE_6_5_P99[name]) < 1e-9
    assert not np.array_equal(a.temperatures["ambient"], c.temperatures["ambient"])
    # sensors read in DS1820 steps of 1/16 K; the C-axis heat shows in coolant out - in
    for v in a.temperatures.values():
        np.testing.assert_allclose(v * 16, np.round(v * 16))
    dt = a.temperatures["c_coolant_out"] - a.temperatures["c_coolant_in"]
    busy = a.machine_state["c_axis_rpm"] > 600
    if busy.any() and (~busy).any():
        assert dt[busy].mean() > dt[~busy].mean()
    rec = a.as_recording()
    assert set(rec.names("sensor")) == {"ambient_c", "ws_c", "c_coolant_in_c", "c_coolant_out_c"}
    assert len(rec.names("error")) == 7
