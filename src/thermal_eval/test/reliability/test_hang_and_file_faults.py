"""The fault-table rows for hangs, the recorder and bad files: each survives with nothing lost."""
from __future__ import annotations

import os

import pytest

from thermal_eval.reliability import hang_and_file_faults as hf
pytestmark = [pytest.mark.slow, pytest.mark.ros]


def test_rows_survive_with_no_data_lost_and_no_unsafe_write(tmp_path, ros_domain_id):
    rows = hf.rows(tmp_path, ros_domain_id)
    assert len(rows) == 7
    for r in rows:
        assert r["survived"], r
        assert r["data_lost"] == 0 and r["unsafe_writes"] == 0, r
