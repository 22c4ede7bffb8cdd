"""Many recordings as one data set: sources and manifests, runs, splits by run."""
from thermal_eval.datasets.run_start import RunStart, decide_run_start
from thermal_eval.datasets.runs import Run, fold_data, load_runs, segments
from thermal_comp_common.recording_sources import DatasetError, RunEntry, read_manifest, resolve_runs
from thermal_comp_common.run_splits import DEFAULT_RUN_SPLIT, RunFold, run_splits

__all__ = ["DEFAULT_RUN_SPLIT", "DatasetError", "Run", "RunEntry", "RunFold", "RunStart", "decide_run_start",
           "fold_data", "load_runs", "read_manifest", "resolve_runs", "run_splits", "segments"]
