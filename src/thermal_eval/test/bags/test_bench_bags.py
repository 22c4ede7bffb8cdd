"""The bags benchmark runs and loses nothing (its figures are measured, never asserted)."""
import argparse

import pytest

from thermal_eval.bench import bags as bench_bags
pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_bench_runs_and_loses_no_message(tmp_path):
    figures = bench_bags.run(argparse.Namespace(quick=True, out_dir=str(tmp_path)))
    assert figures["write"]["messages"] == figures["read"]["messages"] == 600
    assert figures["ros_record"]["lost"] == 0 and figures["ros_record"]["messages"] == 600
    assert figures["ros_replay"]["lost"] == 0 and figures["ros_replay"]["messages"] == 600
    for part in ("write", "read", "ros_record", "ros_replay"):
        assert figures[part]["msgs_per_s"] > 0 and figures[part]["sim_hours_per_s"] > 0
