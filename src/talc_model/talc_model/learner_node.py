"""``learner`` node: the cell's online learner. It learns the unit's twin from the cell's own
recording every ``learn_every_h`` hours of model time and on demand (service ``learn_now``,
std_srvs/Trigger), each time with ``thermal-comp learn`` in a subprocess of its own (killed after
``learn_timeout_s``), and offers a prior learn adopted to the model node (``adopt_prior``). It is no
lock-step participant: the graph never waits for it. Model time comes from ``model_status``.

Run: ``python -m talc_model.learner_node --ros-args -p recording:=demo_out/bag -p twin:=nmv5000
-p work_dir:=demo_out/learn -p learn_every_h:=24``. The work is :mod:`talc_model.online.learner`.
"""
from __future__ import annotations

import pathlib

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from std_srvs.srv import Trigger

from thermal_comp_common.runtime.diagnostics import DiagnosticsPublisher
from thermal_comp_common.runtime.node_runtime import (LATCHED_QOS, TOPIC_MODEL_STATUS, Param, declare_parameters,
                                                      run_node, stamp_to_s)
from thermal_comp_msgs.msg import ModelStatus
from thermal_comp_msgs.srv import AdoptPrior

from talc_model.online.learn_job import parse_command
from talc_model.online.learner import SERVICE_ADOPT_PRIOR, SERVICE_LEARN_NOW, LearnerConfig, OnlineLearner

PARAMS = [
    Param("recording", "", "the cell recorder's bag folder (or .mcap file) to learn from"),
    Param("twin", "", "the type's twin learn starts from: preset name or machine YAML file"),
    Param("work_dir", "", "folder for each learning's snapshot, output and logs"),
    Param("learn_every_h", 0.0, "learn every this many hours of model time; 0 = on demand only", 0.0, 1e6),
    Param("learn_timeout_s", 600.0, "wall-clock limit of one learn subprocess (killed after), s", 1.0, 1e6),
    Param("train_fraction", 0.8, "learn's --train-h as a fraction of the hours recorded so far", 0.06, 0.95),
    Param("learn_command", "", "the learn command line (empty: thermal-comp learn of this environment)"),
    Param("prior_path", "", "the prior the model started from (the audit's old digest until the first answer)"),
    Param("audit_path", "", "audit file (JSON lines); empty = log only"),
    Param("poll_period_s", 0.25, "how often the learner looks at its subprocess (wall clock), s", 0.01, 60.0),
    Param("adopt_wait_s", 30.0, "wall-clock wait for the model node's adopt_prior service, s", 0.1, 3600.0),
]


class LearnerNode(Node):
    def __init__(self, context=None):
        super().__init__("learner", context=context)
        p = declare_parameters(self, PARAMS)
        for name in ("recording", "twin", "work_dir"):
            if not p[name]:
                raise ValueError(f"parameter {name!r}: required")
        self.core = OnlineLearner(LearnerConfig(
            recording=p["recording"], twin=p["twin"], work_dir=str(pathlib.Path(p["work_dir"]).resolve()),
            every_h=p["learn_every_h"], timeout_s=p["learn_timeout_s"], train_fraction=p["train_fraction"],
            command=parse_command(p["learn_command"]), audit_path=p["audit_path"], prior_path=p["prior_path"]))
        self.adopt_wait_s = p["adopt_wait_s"]
        self.wall = Clock(clock_type=ClockType.STEADY_TIME)
        self.diag = DiagnosticsPublisher(self, hardware_id="online learner")
        self.adopt = self.create_client(AdoptPrior, SERVICE_ADOPT_PRIOR)
        self.create_service(Trigger, SERVICE_LEARN_NOW, self._on_learn_now)
        self.create_subscription(ModelStatus, TOPIC_MODEL_STATUS, self._on_status, LATCHED_QOS)
        self.create_timer(p["poll_period_s"], self._poll, clock=self.wall)
        self.offer_deadline = 0.0
        self.pending = False            # an offer is on its way to the model node
        self.diag.set("learner", "OK", "idle")
        self.get_logger().info(f"online learner: {p['recording']} on twin {p['twin']}, every "
                               f"{p['learn_every_h']:g} h of model time (0: on demand)")

    def _now(self) -> float:
        return self.wall.now().nanoseconds * 1e-9

    def _on_status(self, msg: ModelStatus) -> None:
        self.core.observe(stamp_to_s(msg.header.stamp))

    def _on_learn_now(self, req, resp):
        resp.success, resp.message = self.core.request()
        return resp

    def _poll(self) -> None:
        if self.core.poll(self._now()) is not None:
            self.offer_deadline = self._now() + self.adopt_wait_s
        if self.core.offer is not None and not self.pending and self.adopt.service_is_ready():
            self._send(self.core.offer)
        elif self.core.offer is not None and self._now() > self.offer_deadline:
            self.pending = False     # a late answer finds no offer and is ignored; the model node audits
            self.core.answered(False, f"no answer from the model node's adopt_prior within "
                                      f"{self.adopt_wait_s:g} s", "", "")
        self.diag.set("learner", "OK", self.core.last, runs=self.core.runs)

    def _send(self, offer) -> None:
        req = AdoptPrior.Request(prior_path=offer.prior_path, model_config_path=offer.config_path,
                                 report_path=offer.report_path)
        self.pending = True
        self.adopt.call_async(req).add_done_callback(self._on_answer)

    def _on_answer(self, future) -> None:
        self.pending = False
        res = future.result()
        if res is None:
            self.core.answered(False, "adopt_prior call failed", "", "")
        else:
            self.core.answered(res.accepted, res.message, res.old_prior_sha256, res.new_prior_sha256)
        self.get_logger().info(f"online learning: {self.core.last}")

    def close(self) -> None:
        self.core.stop()


def main(args=None) -> int:
    return run_node(LearnerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
