"""``thermal-comp learn`` on several runs of one unit: sources, the joint fit, the report."""
from thermal_eval.learn.runs.command import learn_runs
from thermal_eval.learn.runs.sources import CellRun, cell_runs

__all__ = ["CellRun", "cell_runs", "learn_runs"]
