"""Evaluation of thermal-comp: benchmarks, the FL_THERMAL loader, replay (virtual experiment),
parameter sweep, bag regression and fault injection. See docs/replay_sweep.md and
docs/reliability.md."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "replay.virtual_experiment": ["VirtualExperimentError", "VirtualExperimentResult", "run_virtual_experiment"],
    "sweep.grid": ["SweepError", "SweepPoint", "SweepRun", "run_sweep", "table_6_1_grid"],
    "fl_thermal.data": ["FlThermalData", "FlThermalError", "load_fl_thermal"],
    "replay.bag_regression": ["RegressionError", "RegressionSpec"],
    "reliability.faulted_cell": ["LoopResult", "run_core_loop"],
    "reliability.sensor_faults": ["FaultInjector", "SensorFault"],
    "reliability.process_kills": ["Kill", "KillPlan", "run_graph_faults"],
})
