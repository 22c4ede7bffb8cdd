"""Fault injection for reliability tests and ``thermal-comp bench faults``: one import for
the tools that live in their own modules (sensor faults, offset safety checks, the closed
core loop, CNC-link faults, process kills, probe faults). Policies: docs/reliability.md.
"""
from thermal_eval.reliability.faulted_cell import LoopResult, run_core_loop
from thermal_eval.reliability.link_faults import LinkFaultResult, run_link_fault
from thermal_eval.reliability.offset_safety_checks import (OffsetViolation, offset_violations, step_violations,
                                               written_offsets_um)
from thermal_eval.reliability.probe_faults import FaultyProbeBackend
from thermal_eval.reliability.process_kills import (DEMO_ENVELOPE, Kill, KillPlan, compare_p99, run_graph_faults,
                                        run_recorder_kill)
from thermal_eval.reliability.sensor_faults import FAULT_KINDS, FaultInjector, SensorFault, inject, reorder_late

__all__ = ["DEMO_ENVELOPE", "FAULT_KINDS", "FaultInjector", "FaultyProbeBackend", "Kill", "KillPlan",
           "LinkFaultResult", "LoopResult", "OffsetViolation", "SensorFault", "compare_p99", "inject",
           "offset_violations", "reorder_late", "run_core_loop", "run_graph_faults", "run_link_fault",
           "run_recorder_kill", "step_violations", "written_offsets_um"]
