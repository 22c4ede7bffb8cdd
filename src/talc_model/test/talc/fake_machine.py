"""A fake machine for the talc_model node test (run as a second process): it owns simulated
time like machine_sim and serves the ProbeCycle action like probe_cycle.

Time: it publishes ``temperatures`` (sensors a, b, c) for t_k = k * step and advances to
t_{k+1} only after talc_model acknowledged t_k with SimSync (lock-step). Sensor c reports
FAILED for steps 10..13. The true error is a known static function of the temperatures,
E_X0C = 2 (a - 20) + 1 (b - 20); a probing cycle sees the true error at the current t_k
minus the compensation the model predicted for t_k (as the twin does when the bridge
applies it). Goals listed in ``--fail`` are aborted, goals in ``--hang`` never finish
until cancelled. Each goal is logged as a JSON line (goal number, set_reference, t_k when
it started and ended, measured and true error); ``{"done": true}`` ends the log.

Usage: python fake_machine.py LOG.jsonl --steps 36 --fail 3 --hang 6
"""
import argparse
import json
import math
import sys
import threading
import time

import numpy as np
from rclpy.action import ActionServer, CancelResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Header

from thermal_comp_common.runtime.node_runtime import (ACTION_PROBE_CYCLE, EVENT_QOS, SENSOR_QOS, TOPIC_ERRORS_PREDICTED,
                                       TOPIC_SIM_SYNC, TOPIC_TEMPERATURES, run_node, s_to_stamp, stamp_to_s)
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import SimSync, TemperatureArray, ThermalErrors

ARGS = None
STEP = 300.0


def scenario(n_steps: int, seed: int = 3) -> np.ndarray:
    """Temperatures a, b per step: random steps held two steps, starting at 20 degC."""
    rng = np.random.default_rng(seed)
    temps = 20.0 + np.repeat(rng.uniform(-2, 2, size=(n_steps // 2 + 1, 2)), 2, axis=0)[:n_steps]
    temps[0] = 20.0
    return temps


def true_error(temps_k) -> float:
    return 2.0 * (temps_k[0] - 20.0) + 1.0 * (temps_k[1] - 20.0)


class FakeMachine(Node):
    def __init__(self, context=None):
        super().__init__("fake_machine", context=context)
        group = ReentrantCallbackGroup()
        self.temps = scenario(ARGS.steps)
        self.k = -1                      # index of the last published step
        self.acked = -math.inf
        self.predicted_t, self.predicted = -math.inf, {}
        self.goals = 0
        self.lock = threading.Lock()
        self.pub = self.create_publisher(TemperatureArray, TOPIC_TEMPERATURES, SENSOR_QOS)
        self.create_subscription(SimSync, TOPIC_SIM_SYNC, self._on_sync,
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
                                 callback_group=group)
        self.create_subscription(ThermalErrors, TOPIC_ERRORS_PREDICTED, self._on_pred, EVENT_QOS,
                                 callback_group=group)
        self.server = ActionServer(self, ProbeCycle, ACTION_PROBE_CYCLE, execute_callback=self._execute,
                                   cancel_callback=lambda _h: CancelResponse.ACCEPT, callback_group=group)
        self.create_timer(0.01, self._tick, callback_group=group)
        self.done = False

    def _on_sync(self, msg):
        if msg.node_name == "talc_model":
            with self.lock:
                self.acked = max(self.acked, stamp_to_s(msg.processed_until))

    def _on_pred(self, msg):
        with self.lock:
            self.predicted_t = stamp_to_s(msg.header.stamp)
            self.predicted = dict(zip(msg.component_names, msg.values))

    def _log(self, entry):
        with open(ARGS.log, "a") as f:
            f.write(json.dumps(entry) + "\n")

    def _tick(self):
        with self.lock:
            if self.done:
                return
            if self.k >= 0 and self.acked < self.k * STEP:
                return
            if self.k < 0 and (self.pub.get_subscription_count() < 2 or not self.server_ready()):
                return  # wait for talc_model (and the test's observer) to subscribe
            if self.k + 1 >= ARGS.steps:
                self.done = True
                self._log({"done": True})
                return
            self.k += 1
            k = self.k
        c_failed = 10 <= k < 14
        self.pub.publish(TemperatureArray(
            header=Header(stamp=s_to_stamp(k * STEP)), sensor_ids=["a", "b", "c"],
            temperatures_degc=[float(self.temps[k, 0]), float(self.temps[k, 1]), math.nan if c_failed else 25.0],
            status=[0, 0, TemperatureArray.STATUS_FAILED if c_failed else TemperatureArray.STATUS_OK]))

    def server_ready(self):
        return self.count_subscribers(TOPIC_SIM_SYNC) >= 0 and self.count_publishers(TOPIC_SIM_SYNC) >= 1

    def _execute(self, goal_handle):
        self.goals += 1
        n = self.goals
        k = self.k
        t = k * STEP
        # the model published its prediction for t before sending the goal; wait for it to arrive
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and self.predicted_t < t:
            time.sleep(0.005)
        entry = {"goal": n, "set_reference": bool(goal_handle.request.set_reference), "t_start": t,
                 "prediction_for_t": self.predicted_t == t}
        result = ProbeCycle.Result()
        result.duration_s = 95.0
        if n in ARGS.hang:
            deadline = time.monotonic() + 30.0
            while not goal_handle.is_cancel_requested and time.monotonic() < deadline:
                time.sleep(0.01)
            goal_handle.canceled()
            entry.update(outcome="cancelled", t_end=self.k * STEP)
            self._log(entry)
            result.success, result.message = False, "fake: cancelled"
            return result
        if n in ARGS.fail:
            goal_handle.abort()
            entry.update(outcome="aborted", t_end=self.k * STEP)
            self._log(entry)
            result.success, result.message = False, "fake: missing trigger"
            return result
        e_true = true_error(self.temps[k])
        measured = e_true - self.predicted.get("E_X0C", 0.0)
        errors = ThermalErrors(source=ThermalErrors.SOURCE_MEASURED, model_kind="probe_sphere",
                               component_names=["E_X0C"], values=[measured], units=[ThermalErrors.UNIT_UM],
                               uncertainties=[0.2])
        errors.header.stamp = s_to_stamp(t)
        result.errors = errors
        result.success, result.message = True, "fake: ok"
        goal_handle.succeed()
        entry.update(outcome="ok", t_end=self.k * STEP, measured=measured, true=e_true)
        self._log(entry)
        return result


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("log")
    ap.add_argument("--steps", type=int, default=36)
    ap.add_argument("--fail", type=int, nargs="*", default=[])
    ap.add_argument("--hang", type=int, nargs="*", default=[])
    ARGS, rest = ap.parse_known_args()
    sys.exit(run_node(FakeMachine, [sys.argv[0]] + rest, multi_threaded=True, num_threads=4))
