"""A bag turned back into a recording (thermal_comp_common.bags.recording) holds what was imported."""
from __future__ import annotations

import numpy as np
from bags_helpers import small_recording_csv

from thermal_comp_common.bags.recording import bag_to_recording


def test_recording_rebuilt_from_a_bag_holds_the_imported_values(tmp_path):
    from thermal_comp_common.bags.reader import read_bag
    from thermal_comp_common.bags.csv_to_bag import csv_to_bag
    from thermal_comp_common.recording_csv import read_recording_csv
    csv = small_recording_csv(tmp_path / "r.csv", rows=15)
    csv_to_bag(csv, tmp_path / "bag")
    rec = read_recording_csv(csv)
    back = bag_to_recording(read_bag(tmp_path / "bag"))
    np.testing.assert_array_equal(back.time_s, rec.time_s)
    for c in ("ambient_c", "c_motor_c", "E_X0C", "E_A0C"):
        np.testing.assert_array_equal(back.columns[c], rec.columns[c])
    assert np.isnan(back.columns["ws_mwf_c"][5])
    np.testing.assert_array_equal(back.columns["C_axis_rpm"], rec.columns["c_speed_rpm"])
