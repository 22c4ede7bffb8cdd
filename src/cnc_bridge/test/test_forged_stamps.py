"""A prediction stamped 10^7 s ahead of the graph's clock never freezes the bridge: refused,
never acknowledged, counted on /diagnostics; the honest predictions after it are followed at
the rate limit. The watchdog counts the wall seconds since a fresh prediction arrived."""
from __future__ import annotations

import pytest

from cnc_bridge.bridge_core import BridgeCore
from cnc_bridge.offset_backend import TwinBackend
from cnc_bridge.safety_envelope import LIMIT_RATE, LIMIT_WATCHDOG, EnvelopeConfig, SafetyEnvelope
from cnc_bridge.error_transform import FIVE_AXIS_COMPONENTS

T0 = 100.0
FORGED = T0 + 1e7


class WallClock:
    def __init__(self):
        self.s = 1000.0

    def __call__(self):
        return self.s


def _errors(z_um: float) -> dict[str, float]:
    return {c: (z_um if c == "E_Z0T" else 0.0) for c in FIVE_AXIS_COMPONENTS}


def test_the_watchdog_fires_on_wall_silence_whatever_the_stamps_say():
    wall = WallClock()
    core = BridgeCore(SafetyEnvelope(EnvelopeConfig(watchdog_timeout_s=5.0, watchdog_hold_s=300.0),
                                     enabled=True), TwinBackend(), wall=wall)
    core.activate(True)
    # a fresh prediction stamped 1000 s ahead of the steps that follow (a clock that stalls,
    # or a stamp within the bound but ahead): by the stamps the watchdog would stay quiet
    core.update(T0 + 1000.0, _errors(4.0), {}, fresh=True)
    wall.s += 4.9
    assert not any(a.flags & LIMIT_WATCHDOG for a in core.update(T0 + 1.0, _errors(4.0), {}, fresh=False).axes)
    wall.s += 0.2
    assert core.silent_s() == pytest.approx(5.1)
    held = core.update(T0 + 2.0, _errors(4.0), {}, fresh=False)
    assert all(a.flags & LIMIT_WATCHDOG for a in held.axes) and core.counters.watchdog
    wall.s += 0.1                  # a fresh prediction arrives: the watchdog lets go
    back = core.update(T0 + 1000.0, _errors(4.0), {}, fresh=True)
    assert not any(a.flags & LIMIT_WATCHDOG for a in back.axes) and core.silent_s() == 0.0


# ---------------------------------------------------------------- the node, callbacks driven
@pytest.fixture
def bridge(ros_domain_id):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from thermal_comp_testing.sim_clock import SimClock

    from cnc_bridge.cnc_bridge_node import CncBridgeNode

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", "backend:=twin", "-p", "lockstep:=true",
                                  "-p", "use_sim_time:=true", "-p", "autostart:=true",
                                  "-p", "max_rate_um_per_s:=0.25", "-p", "max_step_s:=10.0",
                                  "-p", "abs_limit_um:=30.0", "-p", "watchdog_timeout_s:=5.0"])
    node = CncBridgeNode(context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    clock = SimClock(ctx, ex, node)
    set_clock = clock.set

    node.acks, node.sent, node.warnings = [], [], []
    node.sync_pub.publish = lambda msg: node.acks.append(msg.processed_until.sec)
    node.offsets_pub.publish = node.sent.append
    node.get_logger().warning = lambda text, **kw: node.warnings.append(text)
    yield node, set_clock
    ex.shutdown()
    clock.destroy()
    node.destroy_node()
    ctx.try_shutdown()


def _prediction(t: float, z_um: float):
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import ThermalErrors as E
    m = E(source=E.SOURCE_PREDICTED, model_kind="test", component_names=list(FIVE_AXIS_COMPONENTS),
          values=list(_errors(z_um).values()), uncertainties=[0.0] * len(FIVE_AXIS_COMPONENTS),
          units=[E.UNIT_UM_PER_M if c in ("E_A0C", "E_B0C", "E_C0C") else E.UNIT_UM
                 for c in FIVE_AXIS_COMPONENTS])
    m.header.stamp = s_to_stamp(t)
    return m


def _z(msg) -> tuple[float, int]:
    i = list(msg.axis_names).index("Z")
    return msg.applied_offsets_um[i], msg.limits_hit[i]


def test_a_forged_prediction_far_ahead_is_refused_and_the_honest_ones_are_followed(bridge):
    node, set_clock = bridge
    for k in range(3):                              # 0, 2.5, 5 um: 0.25 um/s over 10 s steps
        set_clock(T0 + 10.0 * k)
        node._on_prediction(_prediction(T0 + 10.0 * k, 5.0))
    assert _z(node.sent[-1])[0] == pytest.approx(5.0)
    node._on_prediction(_prediction(FORGED, -30.0))       # the attack: one message, 10^7 s ahead
    assert len(node.sent) == 3 and node.acks == [100, 110, 120]
    zs = []
    for k in range(3, 6):                           # honest 10 um predictions
        set_clock(T0 + 10.0 * k)
        node._on_prediction(_prediction(T0 + 10.0 * k, 10.0))
        zs.append(_z(node.sent[-1]))
    assert [z for z, _ in zs] == pytest.approx([7.5, 10.0, 10.0])   # at the rate limit, then there
    assert zs[0][1] == LIMIT_RATE and not any(f & LIMIT_WATCHDOG for _, f in zs)
    assert node.acks == [100, 110, 120, 130, 140, 150]
    said = [w for w in node.warnings if "errors/predicted" in w]
    assert len(said) == 1 and "ahead of the node's clock" in said[0]
    node._diagnose()
    status = next(s for s in node.diag.statuses() if s.name == "cnc_bridge: bridge")
    values = {kv.key: kv.value for kv in status.values}
    assert values["stamps_refused_ahead"] == "1" and "errors/predicted" in values["last_stamp_refused"]
    assert status.level == b"\x01" and "refusing messages stamped off the graph's clock" in status.message


def test_a_forged_machine_state_far_ahead_never_steps_the_envelope(bridge):
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import MachineState
    node, set_clock = bridge
    set_clock(T0)
    node._on_prediction(_prediction(T0, 5.0))
    state = MachineState(axis_names=["X"], axis_positions=[99.0])
    state.header.stamp = s_to_stamp(FORGED)
    node._on_state(state)
    assert node._positions == {} and len(node.sent) == 1
    set_clock(T0 + 10.0)
    node._on_prediction(_prediction(T0 + 10.0, 5.0))
    assert _z(node.sent[-1])[0] == pytest.approx(2.5)
    node._diagnose()
    values = {kv.key: kv.value for s in node.diag.statuses() if s.name == "cnc_bridge: bridge"
              for kv in s.values}
    assert values["stamps_refused_ahead"] == "1" and "machine_state" in values["last_stamp_refused"]
