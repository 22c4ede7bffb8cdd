"""Rows of ``thermal-comp bench faults`` for messages stamped far ahead of the graph's clock:
a forged TemperatureArray fed to the model node, a forged prediction fed to the bridge's
write path. Both in-process on simulated time, so a row takes seconds and says exactly what
the participant kept.

"data lost" counts honest instants the participant did not handle (not modelled and
acknowledged, or not followed); "unsafe writes" counts applied offsets faster than the rate
limit or beyond the absolute limit (:func:`offset_violations`, the project's definition).
"""
from __future__ import annotations

import json
import math
import pathlib
import tempfile

from cnc_bridge.bridge_core import BridgeCore
from cnc_bridge.offset_backend import TwinBackend
from cnc_bridge.safety_envelope import LIMIT_WATCHDOG, EnvelopeConfig, SafetyEnvelope
from thermal_comp_common.stamp_guard import StampGuard, default_max_ahead_s

from thermal_eval.reliability.fault_rows import guarded
from thermal_eval.reliability.offset_safety_checks import offset_violations

#: the forged stamp's lead over the graph's clock, s (the attack's 10^7 s)
FORGED_AHEAD_S = 1e7
LIMIT_UM, RATE_UM_PER_S, STEP_S, WATCHDOG_S = 30.0, 0.25, 10.0, 5.0


def _row(area: str, fault: str, survived: bool, lost: int, unsafe: int, detail: str) -> dict:
    return {"area": area, "fault": fault, "injected": 1, "survived": bool(survived),
            "data_lost": int(lost), "unsafe_writes": int(unsafe), "detail": detail[:90]}


# ---------------------------------------------------------------- the model
def model_row(domain_id: int) -> dict:
    """The talc_model node (in-process, simulated time) gets an honest instant, one
    TemperatureArray stamped 10^7 s ahead, the next honest instant, then shuts down (saving
    its state). Survived: the model's clock never moved to the forged stamp, the saved state
    holds the last honest instant, the refusal is counted on /diagnostics."""
    with tempfile.TemporaryDirectory(prefix="bench_forged_stamp_") as d:
        return _model_case(pathlib.Path(d), domain_id)


def _model_case(d: pathlib.Path, domain_id: int) -> dict:
    # rclpy and the model node only for this row: the other stamp row and the module's
    # importers stay free of ROS
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from talc_model.state_files import saved_time_s
    from talc_model.talc_model_node import TalcModelNode
    from thermal_comp_testing.sim_clock import SimClock

    cfg, state = d / "talc.yaml", d / "model.json"
    cfg.write_text(json.dumps({"component_names": ["E_X0C"], "input_names": ["a", "b"],
                               "model_step_s": 300.0}))
    t0 = 18000.0
    forged = t0 + FORGED_AHEAD_S
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, domain_id=domain_id, args=[
        "--ros-args", "-p", f"model_config:={cfg}", "-p", f"state_path:={state}",
        "-p", "lockstep_participant:=true", "-p", "action_server_wait_s:=0.0", "-p", "use_sim_time:=true"])
    node = ex = clock = None
    try:
        node = TalcModelNode(context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        clock = SimClock(ctx, ex, node)
        acks: list[float] = []
        node.sync_pub.publish = lambda msg: acks.append(msg.processed_until.sec)
        node.get_logger().warning = lambda text, **kw: None     # the row says it
        node.loop.model.probe_due = lambda t: False             # no probing cycles here
        clock.set(t0)
        node._on_temperatures(_temps(t0))
        node._on_temperatures(_temps(forged))                   # the attack
        t_after_attack = node.loop.t_last
        clock.set(t0 + 300.0)
        node._on_temperatures(_temps(t0 + 300.0))
        status = next(s for s in node.diag.statuses() if s.name.endswith(": stamps"))
        refused = int({kv.key: kv.value for kv in status.values}["stamps_refused_ahead"])
        node.close()                                            # the shutdown save
        saved = saved_time_s(state, node.model)
        forged_saved = str(int(forged)) in state.read_text()
    finally:
        if clock is not None:
            clock.destroy()
        if ex is not None:
            ex.shutdown()
        if node is not None:
            node.destroy_node()
        ctx.try_shutdown()
    lost = sum(1 for t in (t0, t0 + 300.0) if int(t) not in acks)
    ok = t_after_attack == t0 and saved == t0 + 300.0 and not forged_saved and refused == 1 and lost == 0
    return _row("stamps", "temperatures stamped 1e7 s ahead -> model", ok, lost, 0,
                f"model clock {t_after_attack:g} s after it; state saved at {saved:g} s; "
                f"{refused} refused")


def _temps(t: float):
    # ROS messages only with the model row's rclpy (see _model_case)
    from thermal_comp_common.runtime.node_runtime import s_to_stamp
    from thermal_comp_msgs.msg import TemperatureArray
    msg = TemperatureArray(sensor_ids=["a", "b"], temperatures_degc=[20.0 + t / 1e5, 21.0], status=[0, 0])
    msg.header.stamp = s_to_stamp(t)
    return msg


# ---------------------------------------------------------------- the bridge
class _Wall:
    """The bridge's wall clock, advanced by the case (simulated: one step per prediction)."""

    def __init__(self) -> None:
        self.s = 0.0

    def __call__(self) -> float:
        return self.s


def bridge_case(honest_after: int = 6, silent_steps: int = 4) -> dict:
    """The bridge's write path as the node drives it: each prediction's stamp checked by the
    node's guard against the graph's clock, accepted ones stepped by :class:`BridgeCore`.
    Honest 5 um predictions, one stamped 10^7 s ahead asking -30 um, ``honest_after`` honest
    10 um ones, then ``silent_steps`` timer updates in which only forged predictions arrive.
    Returns the applied offset per update, the watchdog flag per update, refusals and violations."""
    wall = _Wall()
    env = SafetyEnvelope(EnvelopeConfig(LIMIT_UM, max_rate_um_per_s=RATE_UM_PER_S, max_step_s=STEP_S,
                                        watchdog_timeout_s=WATCHDOG_S, watchdog_hold_s=300.0),
                         enabled=False)
    core = BridgeCore(env, TwinBackend(), kinematic=True, wall=wall)
    core.adopt_held()
    core.activate(True)
    guard = StampGuard("errors/predicted", default_max_ahead_s(0.0, True))
    t0 = 100.0
    times, applied, watchdog, asked = [], [], [], []
    plan = [(t0 + STEP_S * k, 5.0, True) for k in range(3)]
    plan.append((t0 + STEP_S * 2, -30.0, False))                  # forged, at the same clock
    plan += [(t0 + STEP_S * k, 10.0, True) for k in range(3, 3 + honest_after)]
    plan += [(t0 + STEP_S * k, -30.0, False) for k in range(3 + honest_after, 3 + honest_after + silent_steps)]
    for clock_s, z, honest in plan:
        wall.s = clock_s                                          # one wall second per simulated one
        stamp = clock_s if honest else clock_s + FORGED_AHEAD_S
        if guard.check(stamp, clock_s).accepted:
            update = core.update(stamp, {"X": z}, {}, fresh=True)
            asked.append(z)
        else:                                                     # the node's timer step, nothing fresh
            update = core.update(clock_s, {"X": asked[-1]} if asked else None, {}, fresh=False)
        times.append(clock_s)
        applied.append(update.axes[0].applied_um)
        watchdog.append(bool(update.axes[0].flags & LIMIT_WATCHDOG))
    return {"times": times, "applied_um": applied, "watchdog": watchdog, "honest": [h for _, _, h in plan],
            "refused": guard.refused, "violations": offset_violations(times, {"X": applied}, RATE_UM_PER_S,
                                                                      LIMIT_UM, STEP_S)}


def bridge_row() -> dict:
    """Survived: after the forged prediction the offsets follow the honest ones at the rate
    limit up to 10 um, the watchdog stays quiet while honest predictions arrive and fires once
    only forged ones do for longer than its timeout; every forged one refused."""
    r = bridge_case()
    honest = r["honest"]
    n_forged = honest.count(False)
    last_honest = max(i for i, h in enumerate(honest) if h)
    followed = math.isclose(r["applied_um"][last_honest], 10.0, abs_tol=1e-9)
    quiet = not any(r["watchdog"][: last_honest + 1])
    fired = r["watchdog"][-1]
    lost = 0 if followed else 1
    ok = followed and quiet and fired and r["refused"] == n_forged and not r["violations"]
    return _row("stamps", "prediction stamped 1e7 s ahead -> bridge", ok, lost, len(r["violations"]),
                f"offset {r['applied_um'][3]:g} -> {r['applied_um'][last_honest]:g} um at "
                f"{RATE_UM_PER_S:g} um/s; watchdog only after honest ones stop; {r['refused']} refused")


def rows(domain_id: int) -> list[dict]:
    """The forged-stamp rows (a few seconds); a case that raises is one failed row."""
    return (guarded("stamps", "temperatures stamped 1e7 s ahead -> model", lambda: model_row(domain_id))
            + guarded("stamps", "prediction stamped 1e7 s ahead -> bridge", bridge_row))
