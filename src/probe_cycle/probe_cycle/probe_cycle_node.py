"""``probe_cycle`` node: the ProbeCycle action server (sphere cycle, guide-bush cycle).

Run: ``python -m probe_cycle.probe_cycle_node --ros-args -p backend:=twin -p use_sim_time:=true``

A thin shell around :class:`probe_cycle.probe_cycle_engine.ProbeCycleEngine`. It accepts
one goal at a time (the machine has one probe), publishes feedback after every point,
honours cancel requests before the next point, and returns the measured errors with
their uncertainties. Any failure aborts the goal with a message and an empty error set.
The probing goes to the ``twin`` backend (machine_sim's ``twin/touch_probe`` service, in
simulated time) or to the ``cnc`` backend (a ProbeMove method on the CNC over OPC UA).
Health on ``/diagnostics``: ``probe cycle`` -- the last cycle's result (OK, WARN when it
failed, with the message), cycles run, failures.

Stop (SIGINT/SIGTERM): a cycle in flight is ended at once -- the backend's wait is
interrupted (machine_sim may already be gone and would never answer), the goal is aborted
-- and the node waits at most ``stop_wait_s`` for it, so the process exits within the
launcher's grace time instead of sitting out ``touch_timeout_s`` per move.
"""
from __future__ import annotations

import math
import threading

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from thermal_comp_common.frames import MACHINE_BASE_FRAME
from thermal_comp_common.runtime.diagnostics import DiagnosticsPublisher
from thermal_comp_common.runtime.node_runtime import (ACTION_PROBE_CYCLE, Param, declare_parameters,
                                       run_node, s_to_stamp)
from thermal_comp_msgs.action import ProbeCycle
from thermal_comp_msgs.msg import ThermalErrors
from thermal_twin.machine.artefact_geometry import (ARTEFACT_SPHERE, ArtefactGeometry,
                                            GuideBushArtefact, SphereArtefact,
                                            TouchProbeModel)

from probe_cycle.cycle_plan import GuideBushTiming, SphereTiming
from probe_cycle.cycle_result import UNIT_UM_PER_M, CycleLimits, CycleResult
from probe_cycle.probe_backend import ProbeBackend
from probe_cycle.probe_cycle_engine import GoalSpec, ProbeCycleEngine
from probe_cycle.sim_clock_follower import SimClockFollower
from probe_cycle.twin_backend import TwinProbeBackend

# defaults of the geometry: those of thermal_twin.machine.artefact_geometry (what machine_sim uses)
_S, _P, _G = SphereArtefact(), TouchProbeModel(), GuideBushArtefact()

PARAMS = [
    Param("backend", "twin", "where probing moves run", choices=("twin", "cnc")),
    Param("touch_timeout_s", 30.0, "wall-clock wait for one probing move's answer, s", 0.1, 3600.0),
    Param("service_wait_s", 10.0, "twin: wall-clock wait for the twin/touch_probe service, s",
          0.0, 3600.0),
    Param("cnc_endpoint", "opc.tcp://127.0.0.1:4840/thermal-comp/cnc", "cnc: OPC UA endpoint"),
    Param("cnc_probe_object", "ns=2;s=Probe", "cnc: node id of the probing object"),
    Param("cnc_probe_method", "ns=2;s=Probe.ProbeMove", "cnc: node id of the ProbeMove method"),
    Param("cnc_user", "", "cnc: OPC UA user name (empty = anonymous)"),
    Param("cnc_password", "", "cnc: OPC UA password"),
    Param("default_timeout_s", 300.0, "cycle timeout when a goal gives 0, s", 1.0, 86400.0),
    Param("max_fit_residual_rms_um", 2.0, "fail when a centre fit's RMS residual exceeds this, um",
          0.01, 1000.0),
    Param("max_repeat_distance_um", 4.0, "fail when 360 deg and 0 deg centres differ by more, um",
          0.01, 1000.0),
    Param("reference_file", "", "JSON file keeping the reference (zero) cycles; empty = memory"),
    Param("sphere_radius_from_c_axis_mm", _S.radius_from_c_axis_mm,
          "d/2: sphere centre distance from C, mm", 1.0, 2000.0),
    Param("sphere_diameter_mm", _S.diameter_mm, "precision sphere diameter, mm", 1.0, 200.0),
    Param("sphere_centre_height_mm", _S.centre_height_mm,
          "sphere centre above the table surface, mm", 0.0, 1000.0),
    Param("c_axis_x_mm", _S.c_axis_xy_mm[0], "C-axis line, machine X, mm", -5000.0, 5000.0),
    Param("c_axis_y_mm", _S.c_axis_xy_mm[1], "C-axis line, machine Y, mm", -5000.0, 5000.0),
    Param("table_surface_z_mm", _S.table_surface_z_mm, "table surface, machine Z, mm",
          -5000.0, 5000.0),
    Param("stylus_tip_diameter_mm", _P.stylus_tip_diameter_mm, "probe stylus tip diameter, mm",
          0.1, 50.0),
    Param("probe_repeatability_2sigma_um", _P.repeatability_2sigma_um,
          "touch-trigger probe repeatability (2 sigma), um", 0.0, 100.0),
    Param("axis_resolution_um", _P.axis_resolution_um, "axis position resolution of the CNC, um",
          0.0, 100.0),
    Param("guide_bush_face_x_mm", _G.face_x_mm, "guide-bush face, machine X, mm", -5000.0, 5000.0),
    Param("guide_bush_sigma_um", _G.sigma_um, "guide-bush skip scatter (1 sigma), um", 0.0, 100.0),
    Param("guide_bush_level_um", _G.level_spacing_um, "spacing of the discrete skip levels, um",
          0.0, 100.0),
    Param("tool_change_s", 10.0, "time of one tool change, s", 0.0, 600.0),
    Param("indexing_s", 5.0, "time of one C indexing, s", 0.0, 600.0),
    Param("touch_s", 2.0, "time of one sphere touch incl. positioning, s", 0.01, 600.0),
    Param("guide_bush_approach_s", 4.0, "move to and from the guide bush, s", 0.0, 600.0),
    Param("guide_bush_touch_s", 3.0, "time of one torque-limit skip, s", 0.01, 600.0),
    Param("stop_wait_s", 2.0, "at stop: wall s to wait for the cycle in flight to end", 0.0, 60.0),
]


def geometry_from_parameters(p: dict) -> ArtefactGeometry:
    return ArtefactGeometry(
        sphere=SphereArtefact(radius_from_c_axis_mm=p["sphere_radius_from_c_axis_mm"],
                              diameter_mm=p["sphere_diameter_mm"],
                              centre_height_mm=p["sphere_centre_height_mm"],
                              c_axis_xy_mm=(p["c_axis_x_mm"], p["c_axis_y_mm"]),
                              table_surface_z_mm=p["table_surface_z_mm"],
                              b_pivot_z_mm=_S.b_pivot_z_mm),
        probe=TouchProbeModel(repeatability_2sigma_um=p["probe_repeatability_2sigma_um"],
                              axis_resolution_um=p["axis_resolution_um"],
                              stylus_tip_diameter_mm=p["stylus_tip_diameter_mm"]),
        guide_bush=GuideBushArtefact(face_x_mm=p["guide_bush_face_x_mm"],
                                     sigma_um=p["guide_bush_sigma_um"],
                                     level_spacing_um=p["guide_bush_level_um"]))


class ProbeCycleNode(Node):
    def __init__(self, context=None):
        super().__init__("probe_cycle", context=context)
        self._clock_follower = None
        if self.get_parameter("use_sim_time").value:
            self._clock_follower = SimClockFollower(self)
        p = declare_parameters(self, PARAMS)
        self.engine = ProbeCycleEngine(
            geometry_from_parameters(p),
            CycleLimits(max_fit_residual_rms_um=p["max_fit_residual_rms_um"],
                        max_repeat_distance_um=p["max_repeat_distance_um"]),
            SphereTiming(p["tool_change_s"], p["indexing_s"], p["touch_s"]),
            GuideBushTiming(p["guide_bush_approach_s"], p["guide_bush_touch_s"]),
            default_timeout_s=p["default_timeout_s"],
            reference_path=p["reference_file"] or None)
        self.backend = self._make_backend(p)
        self._busy = threading.Lock()
        self._stopping = threading.Event()
        self._stop_wait_s = p["stop_wait_s"]
        self.cycles = self.failures = 0
        self.diag = DiagnosticsPublisher(self, hardware_id=f"probe ({p['backend']} backend)")
        self.diag.set("probe cycle", "OK", "no cycle yet", cycles=0, failures=0)
        self._server = ActionServer(self, ProbeCycle, ACTION_PROBE_CYCLE,
                                    execute_callback=self._execute,
                                    goal_callback=self._on_goal,
                                    cancel_callback=lambda _h: CancelResponse.ACCEPT,
                                    callback_group=ReentrantCallbackGroup())
        self.get_logger().info(f"probe_cycle ready: backend '{p['backend']}', sphere at "
                               f"{p['sphere_radius_from_c_axis_mm']:g} mm from C")

    def _make_backend(self, p: dict) -> ProbeBackend:
        if p["backend"] == "twin":
            return TwinProbeBackend(self, p["touch_timeout_s"], p["service_wait_s"])
        # heavy: asyncua only for the CNC backend
        from probe_cycle.cnc_probe_backend import CncProbeBackend, CncProbeNodes
        user = p["cnc_user"] or None
        return CncProbeBackend(
            p["cnc_endpoint"], CncProbeNodes(p["cnc_probe_object"], p["cnc_probe_method"]),
            user=user, password=(p["cnc_password"] if user else None),
            call_timeout_s=p["touch_timeout_s"],
            clock=lambda: self.get_clock().now().nanoseconds * 1e-9)

    def _on_goal(self, goal) -> GoalResponse:
        if self._stopping.is_set():
            self.get_logger().warning("goal rejected: the node is stopping")
            return GoalResponse.REJECT
        if self._busy.locked():
            self.get_logger().warning("goal rejected: a probing cycle is already running")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle):
        with self._busy:
            g = goal_handle.request
            spec = GoalSpec(artefact=int(g.artefact), set_reference=bool(g.set_reference),
                            points_per_indexing=int(g.points_per_indexing),
                            c_angles_deg=tuple(float(a) for a in g.c_angles_deg),
                            timeout_s=float(g.timeout_s), tool_position=str(g.tool_position))

            def on_point(done, total, move, reply):
                fb = ProbeCycle.Feedback()
                fb.points_done, fb.points_total, fb.stage = done, total, move.stage
                goal_handle.publish_feedback(fb)

            result = self.engine.run(spec, self.backend, on_point,
                                     cancel_requested=lambda: (goal_handle.is_cancel_requested
                                                               or self._stopping.is_set()))
            msg = self._result_msg(result, spec)
            if result.details.get("canceled") and goal_handle.is_cancel_requested:
                goal_handle.canceled()
            elif result.success:
                goal_handle.succeed()
            else:
                goal_handle.abort()
            self._report(result)
            # (rclpy refuses two severities from one call site: two calls)
            if result.success:
                self.get_logger().info(f"probe cycle done: {result.message}")
            else:
                self.get_logger().warning(f"probe cycle FAILED: {result.message}")
            return msg

    def _report(self, result: CycleResult) -> None:
        """The last cycle's result on /diagnostics."""
        self.cycles += 1
        self.failures += 0 if result.success else 1
        self.diag.set("probe cycle", "OK" if result.success else "WARN",
                      ("last cycle ok: " if result.success else "last cycle FAILED: ") + result.message,
                      cycles=self.cycles, failures=self.failures, duration_s=round(float(result.duration_s), 1),
                      fit_residual_rms_um=round(float(result.fit_residual_rms_um), 3))

    def _result_msg(self, result: CycleResult, spec: GoalSpec) -> ProbeCycle.Result:
        out = ProbeCycle.Result()
        out.success = bool(result.success)
        out.message = result.message
        out.duration_s = float(result.duration_s)
        out.fit_residual_rms_um = float(result.fit_residual_rms_um)
        out.repeatability_check_um = float(result.repeatability_check_um)
        e = ThermalErrors()
        e.source = ThermalErrors.SOURCE_MEASURED
        e.header.frame_id = MACHINE_BASE_FRAME
        e.model_kind = "probe_sphere" if spec.artefact == ARTEFACT_SPHERE else "probe_guide_bush"
        e.header.stamp = (s_to_stamp(result.stamp_s) if math.isfinite(result.stamp_s)
                          else self.get_clock().now().to_msg())
        if result.success and result.errors is not None:   # nothing measured on failure
            me = result.errors
            e.component_names = list(me.component_names)
            e.values = [float(v) for v in me.values]
            e.units = [ThermalErrors.UNIT_UM_PER_M if u == UNIT_UM_PER_M else ThermalErrors.UNIT_UM
                       for u in me.units]
            e.uncertainties = [float(u) for u in me.uncertainties]
        out.errors = e
        return out

    def close(self) -> None:
        """End a cycle in flight (its goal is aborted), wait for it at most ``stop_wait_s``,
        then release the server and the backend: nothing holds the process at exit."""
        self._stopping.set()
        self.backend.stop()
        if self._busy.acquire(timeout=self._stop_wait_s):
            self._busy.release()
        else:
            self.get_logger().error(f"stop: the probing cycle in flight did not end within "
                                    f"{self._stop_wait_s:g} s")
        self._server.destroy()
        self.backend.close()
        if self._clock_follower is not None:
            self._clock_follower.close()


def main(args=None) -> int:
    return run_node(ProbeCycleNode, args, multi_threaded=True, num_threads=3)


if __name__ == "__main__":
    raise SystemExit(main())
