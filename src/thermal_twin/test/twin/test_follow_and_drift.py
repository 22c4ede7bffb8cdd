"""Twin words for what units differ in: a boundary that follows another temperature (a chiller
tracking the hall, with a lag) and a slow linear sensor drift. Simulated, stepped online and
read backwards alike; bad fields refused in one line naming the field."""
import numpy as np
import pytest

from thermal_comp_common.recording_csv import Recording
from thermal_twin.machine.schema import MachineSpecError, load_machine
from thermal_twin.physics.thermal_network import ThermalNetwork
from thermal_twin.sim.inputs_timeline import InputsTimeline, timeline_from_recording
from thermal_twin.sim.simulate import TwinStepper, simulate
from thermal_twin.sim.type_soft_sensors import TypeSoftSensors

FOLLOW = {"temperature": "ambient", "gain": 0.8, "offset": 5.0, "tau_s": 3600.0}


def _spec(**changes):
    spec = load_machine("nmv5000").to_dict()
    if "follows" in changes:
        spec["boundaries"]["cooler"] = {"follows": changes["follows"]}
    if "drift" in changes:
        spec["sensors"]["ambient"]["drift_k_per_h"] = changes["drift"]
    return spec


def _hall_step(hours=12.0, step_s=60.0):
    t = np.arange(0.0, hours * 3600.0 + 1.0, step_s)
    hall = np.where(t < 2 * 3600.0, 20.0, 24.0)
    return InputsTimeline(t, {"ambient_degc": hall, "c_speed_rpm": np.full(t.size, 600.0)})


def test_a_following_boundary_lags_its_source_and_stepping_online_reproduces_simulate():
    m = load_machine(_spec(follows=FOLLOW))
    tl = _hall_step()
    r = simulate(m, tl, seed=1)
    cooler = r.boundary_temperatures[:, list(m.boundaries).index("cooler")]
    t = tl.time_s
    assert cooler[0] == pytest.approx(5.0 + 0.8 * 20.0)
    # a first-order lag of the 4 K step: 63 % after one time constant, the rest later
    k = int(np.searchsorted(t, 2 * 3600.0 + 3600.0))
    assert cooler[k] - 21.0 == pytest.approx(0.8 * 4.0 * (1 - np.exp(-1.0)), rel=0.03)
    assert cooler[-1] == pytest.approx(5.0 + 0.8 * 24.0, abs=0.02)
    vals = tl.resolved(m)
    st = TwinStepper(m, {k: float(v[0]) for k, v in vals.items()})
    errs = [st.errors()["E_Z0T"]]
    for k in range(1, t.size):
        st.advance(t[k] - t[k - 1])
        st.set_inputs({n: float(v[k]) for n, v in vals.items()})
        errs.append(st.errors()["E_Z0T"])
    np.testing.assert_allclose(errs, r.errors["E_Z0T"], atol=1e-9)
    # and the chiller that follows changes the machine's errors (it is not a no-op)
    plain = simulate("nmv5000", tl, seed=1)
    assert np.max(np.abs(plain.errors["E_Z0T"] - r.errors["E_Z0T"])) > 0.5


def test_the_network_refuses_a_machine_whose_following_boundary_is_not_lowered():
    with pytest.raises(MachineSpecError, match="boundaries.cooler: follows another temperature"):
        ThermalNetwork(load_machine(_spec(follows=FOLLOW)))


@pytest.mark.parametrize("follows, message", [
    ({"temperature": "nowhere"}, "boundaries.cooler.follows.temperature: 'nowhere' is neither"),
    ({"temperature": "cooler"}, "is the boundary itself"),
    ({"temperature": "ambient", "gain": "one"}, "boundaries.cooler.follows.gain: 'one' is not a number"),
    ({"temperature": "ambient", "tau_s": -5}, "boundaries.cooler.follows.tau_s: -5.0 must be >= 0"),
    ({"temperature": "ambient", "lag": 5}, "boundaries.cooler.follows.lag: 5 is not a known key"),
    ("ambient", "boundaries.cooler.follows: 'ambient' must be a mapping"),
])
def test_bad_follows_fields_are_refused_in_one_line(follows, message):
    with pytest.raises(MachineSpecError, match=message.replace("(", r"\(").replace(".", r"\.")) as exc:
        load_machine(_spec(follows=follows))
    assert "\n" not in str(exc.value)


def test_a_boundary_with_both_a_temperature_and_follows_is_refused():
    spec = _spec()
    spec["boundaries"]["cooler"] = {"temperature": 22.0, "follows": FOLLOW}
    with pytest.raises(MachineSpecError, match="boundaries.cooler: .* exactly one of 'temperature'"):
        load_machine(spec)


@pytest.mark.parametrize("drift, message", [("fast", "is not a number"), (2.0, "must be <= 1"),
                                            (float("nan"), "is not finite")])
def test_bad_drifts_are_refused(drift, message):
    with pytest.raises(MachineSpecError, match=f"sensors.ambient.drift_k_per_h: .*{message}"):
        load_machine(_spec(drift=drift))


def test_a_drifting_hall_sensor_reads_high_by_drift_times_time_and_is_read_backwards():
    m = load_machine(_spec(drift=0.02))
    r = simulate(m, _hall_step(hours=50.0, step_s=600.0), seed=2)
    plain = simulate("nmv5000", _hall_step(hours=50.0, step_s=600.0), seed=2)
    diff = r.sensors["ambient"] - plain.sensors["ambient"]
    assert diff[0] == pytest.approx(0.0, abs=0.07)
    assert diff[-1] == pytest.approx(0.02 * 50.0, abs=0.07)          # noise and 1/16 K steps
    np.testing.assert_allclose(r.errors["E_Z0T"], plain.errors["E_Z0T"])   # the machine does not drift
    # the timeline of a recording and the soft sensors take the hall from the sensor backwards
    rec = Recording(r.time_s, {"ambient_c": r.sensors["ambient"], "c_speed_rpm": r.inputs["c_speed_rpm"]})
    hall = timeline_from_recording(m, rec).values["ambient_degc"]
    np.testing.assert_allclose(hall, r.sensors["ambient"] - 0.02 * r.time_s / 3600.0)
    soft = TypeSoftSensors(m)
    soft.update(36000.0, {"ambient": 21.2}, {})
    assert soft.last_inputs["ambient_degc"] == pytest.approx(21.2 - 0.2)


def test_soft_sensors_of_a_twin_with_a_following_chiller_resume_from_their_state():
    spec = _spec(follows=FOLLOW)
    a, b = TypeSoftSensors(spec), TypeSoftSensors(spec)
    a.update(0.0, {"ambient": 20.0}, {})
    a.update(600.0, {"ambient": 24.0}, {})
    b.restore(a.to_state())
    for s in (a, b):
        s.update(4200.0, {"ambient": 24.0}, {})
    assert a.values() == b.values()
    assert a.stepper.boundary_temperatures()[2] > 5.0 + 0.8 * 20.0 + 0.1     # the chiller has followed
