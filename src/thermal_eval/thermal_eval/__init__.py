"""Evaluation of thermal-comp: benchmarks, the FL_THERMAL loader, replay (virtual experiment),
parameter sweep, bag regression and fault injection. See docs/replay_sweep.md and
docs/reliability.md."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "virtual_experiment": ["VirtualExperimentError", "VirtualExperimentResult", "run_virtual_experiment"],
    "sweep": ["SweepError", "SweepPoint", "SweepRun", "run_sweep", "table_6_1_grid"],
    "fl_thermal_data": ["FlThermalData", "FlThermalError", "load_fl_thermal"],
    "bag_regression": ["RegressionError", "RegressionSpec"],
    "synthetic_plant": ["SyntheticPlant", "make_plant"],
    "core_loop": ["LoopResult", "run_core_loop"],
    "sensor_faults": ["FaultInjector", "SensorFault"],
    "process_kills": ["Kill", "KillPlan", "run_graph_faults"],
})
