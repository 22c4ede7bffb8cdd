"""The cnc_bridge node in its own process: twin backend in lock-step, OPC UA against the emulator."""
from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time

import pytest

from cnc_bridge.audit_log import read_audit_log
from cnc_bridge.cnc_emulator import ENDPOINT_PATH, CncEmulatorThread, EmulatorConfig, free_tcp_port
from cnc_bridge.error_transform import FIVE_AXIS_COMPONENTS

logging.getLogger("asyncua").setLevel(logging.ERROR)
pytestmark = [pytest.mark.slow, pytest.mark.ros]


def spawn_bridge(namespace: str, *params: str, autostart: bool = True,
                 env: dict | None = None) -> subprocess.Popen:
    args = [sys.executable, "-m", "cnc_bridge.cnc_bridge_node", "--ros-args", "-r", f"__ns:={namespace}"]
    for p in list(params) + ([f"autostart:={str(autostart).lower()}"]):
        args += ["-p", p]
    return subprocess.Popen(args, env={**os.environ, **(env or {})}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def stop(p: subprocess.Popen) -> str:
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    return p.stdout.read()


class Cell:
    """The test side: plays machine_sim (machine_state) and talc_model (errors/predicted)."""

    def __init__(self, namespace: str):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, SENSOR_QOS, TOPIC_ERRORS_PREDICTED,
                                               TOPIC_MACHINE_STATE, TOPIC_OFFSETS, TOPIC_SIM_SYNC)
        from thermal_comp_msgs.msg import AxisOffsets, MachineState, SimSync, ThermalErrors
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node("bridge_test_cell", namespace=namespace, context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.state_pub = self.node.create_publisher(MachineState, TOPIC_MACHINE_STATE, SENSOR_QOS)
        self.pred_pub = self.node.create_publisher(ThermalErrors, TOPIC_ERRORS_PREDICTED, EVENT_QOS)
        self.offsets, self.syncs = [], []
        self.subs = [
            self.node.create_subscription(AxisOffsets, TOPIC_OFFSETS, self.offsets.append, EVENT_QOS),
            self.node.create_subscription(SimSync, TOPIC_SIM_SYNC, self.syncs.append, EVENT_QOS)]
        self.MachineState, self.ThermalErrors = MachineState, ThermalErrors

    def spin_until(self, cond, timeout_s: float, what: str):
        deadline = time.monotonic() + timeout_s
        while not cond():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
            self.ex.spin_once(timeout_sec=0.05)

    def wait_matched(self, timeout_s=30.0):
        # both directions matched, or the first (volatile) messages could be lost
        self.spin_until(lambda: self.pred_pub.get_subscription_count() > 0
                        and self.state_pub.get_subscription_count() > 0
                        and all(s.get_publisher_count() > 0 for s in self.subs),
                        timeout_s, "the bridge")

    def state(self, t: float, **axes):
        from thermal_comp_common.runtime.node_runtime import s_to_stamp
        m = self.MachineState()
        m.header.stamp = s_to_stamp(t)
        m.axis_names = list(axes)
        m.axis_positions = [float(v) for v in axes.values()]
        self.state_pub.publish(m)

    def predict(self, t: float, **errors):
        from thermal_comp_common.runtime.node_runtime import s_to_stamp
        E = self.ThermalErrors
        m = E(source=E.SOURCE_PREDICTED, model_kind="test")
        m.header.stamp = s_to_stamp(t)
        values = {c: 0.0 for c in FIVE_AXIS_COMPONENTS}
        values.update(errors)
        m.component_names = list(values)
        m.values = [float(v) for v in values.values()]
        m.units = [E.UNIT_UM_PER_M if c in ("E_A0C", "E_B0C", "E_C0C") else E.UNIT_UM for c in values]
        m.uncertainties = [float("nan")] * len(values)
        self.pred_pub.publish(m)

    def answer_for(self, t: float, timeout_s=15.0):
        from thermal_comp_common.runtime.node_runtime import stamp_to_s
        self.spin_until(lambda: any(abs(stamp_to_s(s.processed_until) - t) < 1e-9 for s in self.syncs),
                        timeout_s, f"SimSync for t={t}")
        self.spin_until(lambda: any(abs(stamp_to_s(o.header.stamp) - t) < 1e-9 for o in self.offsets),
                        timeout_s, f"offsets for t={t}")
        return next(o for o in self.offsets if abs(stamp_to_s(o.header.stamp) - t) < 1e-9)

    def set_param(self, node_path: str, name: str, value):
        """Set one parameter through the node's service; returns the SetParametersResult."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        cli = self.node.create_client(SetParameters, f"{node_path}/set_parameters")
        self.spin_until(cli.service_is_ready, 15, "the parameter service")
        fut = cli.call_async(SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()]))
        self.spin_until(fut.done, 15, "set_parameters")
        self.node.destroy_client(cli)
        return fut.result().results[0]

    def set_enable(self, node_path: str, value: bool):
        assert self.set_param(node_path, "enable", value).successful

    def transition(self, node_path: str, name: str) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        cli = self.node.create_client(ChangeState, f"{node_path}/change_state")
        self.spin_until(cli.service_is_ready, 15, "the lifecycle service")
        req = ChangeState.Request()
        req.transition.id = getattr(Transition, f"TRANSITION_{name.upper()}")
        fut = cli.call_async(req)
        self.spin_until(fut.done, 30, f"transition {name}")
        self.node.destroy_client(cli)
        return fut.result().success

    def close(self):
        self.node.destroy_node()
        self.ctx.try_shutdown()


def test_twin_backend_in_lockstep(tmp_path, ros_domain_id):
    audit = tmp_path / "audit.csv"
    proc = spawn_bridge("/bridge_twin", "backend:=twin", "lockstep:=true", "abs_limit_um:=15.0",
                        "max_rate_um_per_s:=0.5", "max_step_s:=10.0", f"audit_log_path:={audit}",
                        "watchdog_timeout_s:=30.0", "watchdog_hold_s:=0.0", "watchdog_ramp_um_per_s:=1.0")
    cell = Cell("/bridge_twin")
    try:
        cell.wait_matched()
        applied_z, flags_z = [], []
        for k in range(5):
            t = 100.0 + 10.0 * k
            cell.state(t)            # like machine_sim: no axis positions -> evaluated at the origin
            cell.predict(t, E_Z0T=20.0)
            msg = cell.answer_for(t)
            z = msg.axis_names.index("Z")
            assert msg.commanded_offsets_um[z] == pytest.approx(20.0)
            assert msg.applied[z] and msg.compensation_enabled
            applied_z.append(msg.applied_offsets_um[z])
            flags_z.append(msg.limits_hit[z])
        # the SimSync of an instant comes after its audit lines are on disk (no waiting here)
        assert len([r for r in read_audit_log(audit) if not r["note"]]) == 5 * 3
        # first instant: no time passed; then 0.5 um/s * 10 s per step, clamped at 15 um
        assert applied_z == pytest.approx([0.0, 5.0, 10.0, 15.0, 15.0])
        assert flags_z[1] == 3 and flags_z[4] == 1     # absolute|rate, then absolute only
        cell.set_enable("/bridge_twin/cnc_bridge", False)  # disabled at run time: ramp to zero
        cell.predict(150.0, E_Z0T=20.0)
        msg = cell.answer_for(150.0)
        z = msg.axis_names.index("Z")
        assert msg.applied_offsets_um[z] == pytest.approx(10.0) and msg.limits_hit[z] == 8
        assert not msg.compensation_enabled
        cell.set_enable("/bridge_twin/cnc_bridge", True)
        cell.predict(160.0, E_Z0T=float("nan"))         # bad input: not fresh, but still answered
        msg = cell.answer_for(160.0)
        assert msg.applied_offsets_um[msg.axis_names.index("Z")] == pytest.approx(15.0)
        # predictions stop: machine_state instants drive the watchdog (last fresh one at 150 s,
        # timeout 30 s, no hold): at 200 s it ramps 1 um/s over the capped 10 s step
        from thermal_comp_common.runtime.node_runtime import stamp_to_s
        cell.state(200.0)
        cell.spin_until(lambda: stamp_to_s(cell.offsets[-1].header.stamp) == 200.0, 15, "watchdog")
        msg = cell.offsets[-1]
        z = msg.axis_names.index("Z")
        assert msg.applied_offsets_um[z] == pytest.approx(5.0) and msg.limits_hit[z] == 4
        # the writes: the audit line of a write follows its offsets message (it is on disk
        # before the lock-step acknowledgement; the watchdog's write at 200 s has none)
        writes = lambda: [r for r in read_audit_log(audit) if not r["note"]]   # noqa: E731
        cell.spin_until(lambda: len(writes()) >= 8 * 3, 15, "the audit line of the last write")
        rows = writes()
        assert len(rows) == 8 * 3 and {r["axis"] for r in rows} == {"X", "Y", "Z"}
    finally:
        cell.close()
        out = stop(proc)
    assert "E_Z0T" in out and "nan" in out             # the bad prediction was named in the log


def test_opcua_backend_against_the_emulator(tmp_path, ros_domain_id):
    port = free_tcp_port()
    emu = CncEmulatorThread(EmulatorConfig(port=port, user="cnc", password="pw")).start()
    emu.set_position("B", 90.0)                        # the bridge reads B from the CNC
    proc = spawn_bridge("/bridge_opcua", "backend:=opcua",
                        f"endpoint:=opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}", "lockstep:=true",
                        "max_rate_um_per_s:=1.0", "abs_limit_um:=50.0",
                        f"audit_log_path:={tmp_path / 'audit.csv'}",
                        env={"THERMAL_COMP_OPCUA_USER": "cnc", "THERMAL_COMP_OPCUA_PASSWORD": "pw"})
    cell = Cell("/bridge_opcua")
    try:
        cell.wait_matched()
        for k in range(4):
            t = 10.0 * k
            cell.state(t, X=0.0, Y=0.0, Z=0.0)        # no B in machine_state
            cell.predict(t, E_X0C=10.0, E_Y0C=4.0)
            msg = cell.answer_for(t)
        # B = 90 deg: E_X0C moves to -Z (eq. 6.5), E_Y0C stays on Y; 1 um/s for 10 s reached both
        got = dict(zip(msg.axis_names, msg.applied_offsets_um))
        assert got == pytest.approx({"X": 0.0, "Y": 4.0, "Z": -10.0}, abs=1e-9)
        assert all(msg.applied)
        assert emu.applied_um() == pytest.approx(got, abs=1e-9)   # what the CNC holds = read-back
    finally:
        cell.close()
        stop(proc)
        emu.close()


def test_emulator_command_line(tmp_path):
    from cnc_bridge.opcua_backend import OpcUaBackend
    from cnc_bridge.opcua_config import OpcUaConfig
    help_text = subprocess.run([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--help"],
                               capture_output=True, text=True, timeout=60)
    assert help_text.returncode == 0 and "--security" in help_text.stdout
    port = free_tcp_port()
    proc = subprocess.Popen([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            start_new_session=True)
    try:
        assert "listening on" in proc.stdout.readline()     # the readiness line
        be = OpcUaBackend(OpcUaConfig(endpoint=f"opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}"))
        try:
            assert be.wait_connected(15), be.last_error
            assert be.write_offsets({"Y": 2.5}) == {"Y": pytest.approx(2.5)}
        finally:
            be.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=15) == 0
    bad = subprocess.run([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--security", "required"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--certificate" in bad.stderr
    plain = subprocess.run([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--password", "pw"],
                           capture_output=True, text=True, timeout=60)
    assert plain.returncode == 2, "a password on the command line is not an option"


def test_emulator_fed_by_the_twin_answers_probe_moves_from_ground_truth(ros_domain_id):
    import asyncio

    import numpy as np
    from asyncua import Client, ua

    from cnc_bridge.cnc_emulator import PROBE_METHOD_ID, PROBE_OBJECT_ID, position_node_id
    from thermal_comp_common.runtime.node_runtime import EVENT_QOS, TOPIC_ERRORS_TRUE, s_to_stamp
    from thermal_twin.machine.artefact_geometry import nominal_sphere_centre, touch_trigger_position

    port = free_tcp_port()
    proc = subprocess.Popen([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--twin", "--port",
                             str(port), "--ros-args", "-r", "__ns:=/emu_twin"],
                            env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    cell = Cell("/emu_twin")
    truth_pub = cell.node.create_publisher(cell.ThermalErrors, TOPIC_ERRORS_TRUE, EVENT_QOS)
    url = f"opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}"
    centre = nominal_sphere_centre(0.0)
    start = [float(centre[0]), float(centre[1]), float(centre[2]) + 40.0]

    async def read_x():
        async with Client(url) as c:
            return await c.get_node(position_node_id("X")).read_value()

    async def probe():
        async with Client(url) as c:
            return await c.get_node(PROBE_OBJECT_ID).call_method(
                ua.NodeId.from_string(PROBE_METHOD_ID), ua.Variant(0, ua.VariantType.UInt32),
                0.0, 0.0, start, [0.0, 0.0, -1.0], 80.0)
    try:
        assert "listening on" in proc.stdout.readline()
        cell.spin_until(lambda: cell.state_pub.get_subscription_count() > 0
                        and truth_pub.get_subscription_count() > 0, 30, "the emulator's feed")
        cell.state(5.0, X=123.5, Y=0.0, Z=0.0, B=0.0, C=0.0)
        truth = cell.ThermalErrors(source=cell.ThermalErrors.SOURCE_GROUND_TRUTH, model_kind="twin",
                                   component_names=["E_Z0T", "E_X0C"], values=[12.0, -3.0],
                                   units=[0, 0], uncertainties=[0.0, 0.0])
        truth.header.stamp = s_to_stamp(5.0)
        truth_pub.publish(truth)
        deadline = time.monotonic() + 15
        while asyncio.run(read_x()) != 123.5:
            assert time.monotonic() < deadline, "position never reached the emulator"
            cell.ex.spin_once(timeout_sec=0.05)
        want_trig, want_pos = touch_trigger_position(0, 0.0, 0.0, np.array(start), np.array([0.0, 0.0, -1.0]),
                                                     80.0, {"E_Z0T": 12.0, "E_X0C": -3.0},
                                                     {"X": 0.0, "Y": 0.0, "Z": 0.0})
        assert want_trig
        deadline = time.monotonic() + 15     # the truth message may land a moment after the state
        while True:
            triggered, pos = asyncio.run(probe())
            if triggered and np.allclose(pos, want_pos, atol=1e-9, rtol=0):
                break
            assert time.monotonic() < deadline, f"probe answered {triggered}, {pos}; want {want_pos}"
            cell.ex.spin_once(timeout_sec=0.05)
    finally:
        cell.close()
        stop(proc)


def test_credentials_as_parameters_are_refused(ros_domain_id):
    proc = spawn_bridge("/bridge_secret", "backend:=opcua", "password:=s3cret")
    out = stop(proc) if proc.wait(timeout=60) is None else proc.stdout.read()
    assert proc.returncode == 2
    assert "parameter 'password'" in out and "credentials_file" in out and "s3cret" not in out


def test_managed_bridge_never_writes_before_activate_and_honours_runtime_limits(tmp_path, ros_domain_id):
    """End to end: the CNC holds X = -5 mm with compensation off. Configure connects
    and reads, writes nothing; activate writes from zero, rate-limited (no 5 mm step); a limit
    set at run time applies to the next write; a read-only parameter is refused; deactivate
    ramps to zero."""
    from cnc_bridge.cnc_emulator import EmulatorState, compensation_node_id
    port = free_tcp_port()
    state = EmulatorState(compensation={"X": {"SD43900": -5.0, "SD43910": 0.0, "SD43920": 0.0,
                                              "MD32750": 0}})
    emu = CncEmulatorThread(EmulatorConfig(port=port, offset_limit_mm=10.0))
    emu.start(state)
    audit = tmp_path / "audit.csv"
    proc = spawn_bridge("/bridge_managed", "backend:=opcua",
                        f"endpoint:=opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}", "lockstep:=true",
                        "max_rate_um_per_s:=1.0", "abs_limit_um:=30.0", "max_step_s:=10.0",
                        "disable_ramp_um_per_s:=1.0", f"audit_log_path:={audit}", autostart=False)
    cell = Cell("/bridge_managed")
    node = "/bridge_managed/cnc_bridge"
    try:
        assert cell.transition(node, "configure")
        cell.wait_matched()
        assert emu.write_log == [], "configure never writes"
        notes = [r["note"] for r in read_audit_log(audit) if r["note"]]
        assert any("X: held -5000.000 um (compensation off), adopted 0.000 um" in n for n in notes)
        cell.state(0.0, X=0.0, Y=0.0, Z=0.0)
        cell.predict(0.0, E_X0C=20.0)
        cell.spin_until(lambda: len(cell.syncs) >= 1, 15, "SimSync while inactive")
        assert emu.write_log == [] and cell.offsets == [], "inactive: nothing written"
        assert cell.transition(node, "activate")
        xs = []
        for k in range(1, 4):
            t = 10.0 * k
            cell.state(t, X=0.0, Y=0.0, Z=0.0)
            cell.predict(t, E_X0C=20.0)
            msg = cell.answer_for(t)
            xs.append(dict(zip(msg.axis_names, msg.applied_offsets_um))["X"])
            if k == 1:     # the dropped -5 mm is flagged once, in the first offsets message
                assert msg.limits_hit[msg.axis_names.index("X")] & 8
            else:
                assert not msg.limits_hit[msg.axis_names.index("X")] & 8
        assert xs == pytest.approx([0.0, 10.0, 20.0])         # from zero, 1 um/s, never -5 mm
        assert all(abs(v) <= 30e-3 + 1e-12 for n, v in emu.write_log
                   if n == compensation_node_id("X", "SD43900"))
        assert cell.set_param(node, "abs_limit_um", 1.0).successful
        refused = cell.set_param(node, "endpoint", "opc.tcp://10.0.0.1:4840/x")
        assert not refused.successful and "read-only" in refused.reason.lower()
        cell.predict(40.0, E_X0C=20.0)
        msg = cell.answer_for(40.0)
        x = msg.axis_names.index("X")
        assert msg.commanded_offsets_um[x] == pytest.approx(20.0)
        assert msg.limits_hit[x] & 1, "the new absolute limit is applied and flagged"
        assert msg.applied_offsets_um[x] == pytest.approx(10.0)   # moving to 1 um at 1 um/s
        wider = cell.set_param(node, "abs_limit_um", 30.0)       # widening while active: refused
        assert not wider.successful and "widens the safety envelope" in wider.reason
        assert cell.transition(node, "deactivate")
        cell.predict(50.0, E_X0C=20.0)
        msg = cell.answer_for(50.0)
        assert not msg.compensation_enabled
        assert msg.applied_offsets_um[msg.axis_names.index("X")] == pytest.approx(0.0)
        assert cell.set_param(node, "abs_limit_um", 30.0).successful   # inactive: may widen
        notes = [r["note"] for r in read_audit_log(audit) if r["note"]]
        assert any("abs_limit_um: 30.0 -> 1.0" in n for n in notes)
        assert any("abs_limit_um: 1.0 -> 30.0" in n for n in notes)
    finally:
        cell.close()
        stop(proc)
        emu.close()


def test_wall_clock_deactivate_ramps_the_cnc_to_zero_within_the_rate(tmp_path, ros_domain_id):
    """A bridge on a real clock: deactivate returns once the CNC is back at zero, every step
    within the disable ramp rate (a clean stop by the launcher then leaves nothing applied)."""
    from cnc_bridge.cnc_emulator import compensation_node_id
    port = free_tcp_port()
    emu = CncEmulatorThread(EmulatorConfig(port=port)).start()
    proc = spawn_bridge("/bridge_ramp", "backend:=opcua",
                        f"endpoint:=opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}", "update_period_s:=0.1",
                        "max_rate_um_per_s:=20.0", "disable_ramp_um_per_s:=4.0", "max_step_s:=0.5",
                        "deactivate_wait_s:=10.0", autostart=False)
    cell = Cell("/bridge_ramp")
    node = "/bridge_ramp/cnc_bridge"
    try:
        assert cell.transition(node, "configure") and cell.transition(node, "activate")
        cell.spin_until(lambda: cell.pred_pub.get_subscription_count() > 0
                        and cell.subs[0].get_publisher_count() > 0, 30, "the bridge (no lock-step)")
        cell.predict(time.time(), E_X0C=2.0)
        cell.spin_until(lambda: abs(emu.applied_um()["X"] - 2.0) < 1e-9, 20, "X at 2 um on the CNC")
        n = len(emu.write_log)
        assert cell.transition(node, "deactivate")
        assert emu.applied_um()["X"] == pytest.approx(0.0, abs=1e-12), "at zero when deactivate returns"
        ramp = [v * 1000.0 for nid, v in emu.write_log[n:] if nid == compensation_node_id("X", "SD43900")]
        assert ramp[-1] == 0.0 and len(ramp) >= 4          # 2 um at 4 um/s in 0.1 s steps: a ramp
        assert all(abs(a - b) <= 4.0 * 0.5 + 1e-9 for a, b in zip([2.0] + ramp, ramp))
    finally:
        cell.close()
        stop(proc)
        emu.close()
