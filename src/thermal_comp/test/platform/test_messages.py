"""Every interface of thermal_comp_msgs: constructed, serialized, deserialized, constants present."""
from __future__ import annotations

import math

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import (AxisOffsets, MachineState, ModelStatus, SimSync, TemperatureArray,
                                   ThermalErrors)
from thermal_comp_msgs.srv import TouchProbe


def _roundtrip(msg):
    data = serialize_message(msg)
    assert isinstance(data, bytes) and len(data) > 4
    back = deserialize_message(data, type(msg))
    assert back == msg, f"{type(msg).__name__} changed in a serialize/deserialize round trip"
    return back


def test_temperature_array():
    m = TemperatureArray(sensor_ids=["ambient", "mwf_nozzle", "c_in"], temperatures_degc=[21.5, 24.25, -3.0],
                         status=[TemperatureArray.STATUS_OK, TemperatureArray.STATUS_STALE,
                                 TemperatureArray.STATUS_OUT_OF_RANGE])
    m.header.stamp.sec = 3600
    m.header.frame_id = "nmv5000"
    back = _roundtrip(m)
    assert list(back.temperatures_degc) == [21.5, 24.25, -3.0]
    assert {TemperatureArray.STATUS_OK, TemperatureArray.STATUS_STALE, TemperatureArray.STATUS_OUT_OF_RANGE,
            TemperatureArray.STATUS_FAILED} == {0, 1, 2, 3}
    failed = TemperatureArray(sensor_ids=["x"], temperatures_degc=[math.nan], status=[TemperatureArray.STATUS_FAILED])
    assert math.isnan(deserialize_message(serialize_message(failed), TemperatureArray).temperatures_degc[0])


def test_machine_state():
    m = MachineState(spindle_names=["main_spindle"], spindle_speeds_rpm=[8000.0],
                     rotary_axis_names=["B", "C"], rotary_axis_speeds_rpm=[0.0, 600.0],
                     axis_names=["X", "Y", "Z", "B", "C"], axis_positions=[100.0, -50.0, 200.0, 45.0, 90.0],
                     coolant_on=True, coolant_temperature_degc=22.0, door_open=False,
                     drive_names=["X", "C"], drive_powers_w=[350.0, 1200.0], machine_busy_probing=False)
    back = _roundtrip(m)
    assert back.axis_names[3] == "B" and back.axis_positions[3] == 45.0


def test_thermal_errors():
    names = ["E_X0C", "E_Y0C", "E_Z0T", "E_R0T", "E_A0C", "E_B0C", "E_C0C"]
    units = [ThermalErrors.UNIT_UM] * 4 + [ThermalErrors.UNIT_UM_PER_M] * 3
    for source in (ThermalErrors.SOURCE_MEASURED, ThermalErrors.SOURCE_PREDICTED, ThermalErrors.SOURCE_GROUND_TRUTH):
        m = ThermalErrors(source=source, model_kind="talc", component_names=names,
                          values=[1.0, -2.0, 3.0, 0.5, 10.0, -4.0, 2.0], units=units,
                          uncertainties=[0.3] * 4 + [1.2] * 3)
        _roundtrip(m)
    assert (ThermalErrors.UNIT_UM, ThermalErrors.UNIT_UM_PER_M) == (0, 1)


def test_axis_offsets():
    m = AxisOffsets(axis_names=["X", "Y", "Z"], commanded_offsets_um=[5.0, -30.0, 12.0],
                    applied_offsets_um=[5.0, -20.0, 11.0], applied=[True, True, False],
                    limits_hit=[AxisOffsets.LIMIT_NONE, AxisOffsets.LIMIT_ABSOLUTE,
                                AxisOffsets.LIMIT_RATE | AxisOffsets.LIMIT_WRITE_FAILED],
                    compensation_enabled=True)
    back = _roundtrip(m)
    assert back.limits_hit[2] & AxisOffsets.LIMIT_RATE and back.limits_hit[2] & AxisOffsets.LIMIT_WRITE_FAILED
    flags = [AxisOffsets.LIMIT_ABSOLUTE, AxisOffsets.LIMIT_RATE, AxisOffsets.LIMIT_WATCHDOG,
             AxisOffsets.LIMIT_DISABLED, AxisOffsets.LIMIT_WRITE_FAILED]
    assert sorted(flags) == [1, 2, 4, 8, 16], "limit flags must be distinct bits"


def test_model_status_and_sim_sync():
    m = ModelStatus(model_kind="talc", phase=ModelStatus.PHASE_NO_GOOD, probing_cycles=12,
                    failed_probing_cycles=1, no_good_phases=2, parameter_updates=3, training_samples=5000,
                    q_prod_pct=97.5, max_uncertainty=1.2, excluded_sensor_ids=["c_out"], message="limit")
    m.next_probing_due.sec = 7200
    _roundtrip(m)
    assert (ModelStatus.PHASE_CALIBRATION, ModelStatus.PHASE_COMPENSATION, ModelStatus.PHASE_NO_GOOD) == (0, 1, 2)
    s = SimSync(node_name="talc_model")
    s.processed_until.sec = 60
    _roundtrip(s)


def test_touch_probe_service():
    req = TouchProbe.Request(artefact=TouchProbe.Request.ARTEFACT_SPHERE, c_axis_deg=90.0, b_axis_deg=0.0,
                             max_travel_mm=5.0, duration_s=4.0)
    req.start_mm = [160.0, 0.0, 30.0]
    req.direction = [-1.0, 0.0, 0.0]
    _roundtrip(req)
    resp = TouchProbe.Response(triggered=True, message="ok")
    resp.trigger_position_mm = [152.5, 0.001, 30.0]
    assert list(_roundtrip(resp).trigger_position_mm) == [152.5, 0.001, 30.0]


@pytest.mark.parametrize("part", ["Goal", "Result", "Feedback"])
def test_probe_cycle_action_parts(part):
    cls = getattr(ProbeCycle, part)
    m = cls()
    if part == "Goal":
        m.artefact = ProbeCycle.Goal.ARTEFACT_GUIDE_BUSH
        m.c_angles_deg = [0.0, 90.0, 180.0, 270.0, 360.0]
        m.points_per_indexing = 5
        m.timeout_s = 300.0
        m.tool_position = "GB"
    elif part == "Result":
        m.success = False
        m.message = "no trigger at C=90"
        m.errors.component_names = ["GB_X"]
        m.errors.values = [1.5]
        m.errors.units = [0]
        m.errors.uncertainties = [0.3]
    else:
        m.points_done, m.points_total, m.stage = 3, 20, "C=90"
    _roundtrip(m)
