"""Which recordings make a data set: its one definition lives in
:mod:`thermal_comp_common.recording_sources`, below both thermal_eval and thermal_twin, so that
``calibrate`` (thermal_twin, which cannot import thermal_eval) takes the same sources."""
from thermal_comp_common.recording_sources import (META_FIELDS, RECORDING_SUFFIXES, DatasetError, RunEntry,
                                                   is_manifest, read_manifest, resolve_runs)

__all__ = ["META_FIELDS", "RECORDING_SUFFIXES", "DatasetError", "RunEntry", "is_manifest", "read_manifest",
           "resolve_runs"]
