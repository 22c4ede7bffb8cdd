"""A short twin recording shared by the replay and sweep tests."""
from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def short_csv(tmp_path_factory):
    """12 h of the twin's load case A written in the shared recording CSV format."""
    from thermal_comp_common.recording_csv import write_recording_csv
    from thermal_twin.sim.scenarios import make_timeline
    from thermal_twin.sim.simulate import simulate
    path = tmp_path_factory.mktemp("rec") / "load_case_a_12h.csv"
    rec = simulate("nmv5000", make_timeline("nmv5000", "load-case-A", hours=12.0, seed=3), seed=3).to_recording()
    write_recording_csv(path, rec.time_s, rec.columns)
    return path
