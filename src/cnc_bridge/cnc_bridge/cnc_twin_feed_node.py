"""cnc_twin_feed: drive the CNC emulator from the running twin (the demo's CNC).

Subscribes to machine_sim's ``machine_state`` (axis positions -> the emulator's
``Axis.<A>.Position`` nodes) and ``errors/ground_truth`` (the true thermal errors that the
emulator's ``ProbeMove`` answers from, through ``thermal_twin.machine.artefact_geometry`` and the
compensation the emulator applies at that moment). So an OPC UA client - the cnc_bridge
node writing offsets, the probe cycle's ``cnc`` backend probing - talks to the twin as to a
real controller.

Run: ``thermal-comp cnc-emulator --twin [--port P ...] [--ros-args -r __ns:=/cell1]``.
"""
from __future__ import annotations

import math
from typing import Callable

from rclpy.node import Node

from thermal_comp_common.runtime.node_runtime import SENSOR_QOS, TOPIC_ERRORS_TRUE, TOPIC_MACHINE_STATE, EVENT_QOS
from thermal_comp_msgs.msg import MachineState, ThermalErrors

from cnc_bridge.cnc_emulator.thread import CncEmulatorThread


class CncTwinFeed(Node):
    def __init__(self, context=None, emulator: CncEmulatorThread | None = None,
                 on_true_errors: Callable[[dict[str, float]], None] | None = None):
        super().__init__("cnc_twin_feed", context=context)
        if emulator is None:
            raise ValueError("cnc_twin_feed runs inside 'thermal-comp cnc-emulator --twin'")
        self.emulator = emulator
        self._on_true_errors = on_true_errors or (lambda errors: None)
        self.create_subscription(MachineState, TOPIC_MACHINE_STATE, self._on_state, SENSOR_QOS)
        self.create_subscription(ThermalErrors, TOPIC_ERRORS_TRUE, self._on_truth, EVENT_QOS)
        self.get_logger().info(f"CNC emulator on {emulator.config.endpoint}, fed by the twin")

    def _on_state(self, msg: MachineState) -> None:
        known = self.emulator.emulator.state.positions
        positions = {a: float(v) for a, v in zip(msg.axis_names, msg.axis_positions)
                     if a in known and math.isfinite(v)}
        if positions:
            self.emulator.set_positions(positions)

    def _on_truth(self, msg: ThermalErrors) -> None:
        if len(msg.component_names) != len(msg.values):
            self.get_logger().error(f"errors/ground_truth: {len(msg.component_names)} names but "
                                    f"{len(msg.values)} values; ignored")
            return
        self._on_true_errors({n: float(v) for n, v in zip(msg.component_names, msg.values)
                              if math.isfinite(v)})
