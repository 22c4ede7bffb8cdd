"""Several machine cells at once, each its own namespace and ROS_DOMAIN_ID (the counterpart
of the 20-cell load benchmark in ``thermal-comp bench faults``, kept tiny)."""
from __future__ import annotations

import pytest

from thermal_eval.bench.faults import load_figures


@pytest.mark.slow
@pytest.mark.ros
def test_two_cells_side_by_side_lose_no_message(tmp_path):
    f = load_figures(tmp_path, cells=2, hours=1.5, wall_timeout_s=240.0)
    assert f["finished"], f
    assert f["instants_recorded"] >= 2 * 18          # 1.5 h on the 5-min grid, per cell
    assert f["instants_missing"] == {"temperatures": 0, "errors/predicted": 0, "offsets": 0}, f
    assert set(f["peak_rss_mb_per_node"]) == {"machine_sim", "sensors", "probe_cycle", "model", "bridge",
                                              "frames", "recorder"}
    assert all(v > 0 for v in f["cpu_s_per_node_per_cell"].values())
