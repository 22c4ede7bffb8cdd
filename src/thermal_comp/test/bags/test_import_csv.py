"""import-csv: recording CSVs become bags of our message types, values unchanged."""
import math
import subprocess
import sys

import numpy as np
import pytest

from bags_helpers import env, small_recording_csv
from thermal_comp_common.bags import msg_definitions as md
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.csv_to_bag import CsvImportError, csv_to_bag, represented_inputs
from thermal_comp_common.recording_csv import read_recording_csv, write_recording_csv


def _decoded(bag, topic):
    store = md.typestore()
    return [store.deserialize_cdr(m.data, m.type) for m in read_bag(bag).messages if m.topic == topic]


def test_fl_thermal_slice_is_imported_unchanged(shared_dir, tmp_path):
    csv = shared_dir / "data" / "fl_thermal" / "fl_thermal.csv"
    res = csv_to_bag(csv, tmp_path / "fl", errors_as="measured", rows=(100, 400), every=3)
    assert res.rows == 100 and res.unmapped == []
    rec = read_recording_csv(csv)
    idx = np.arange(100, 400, 3)
    temps = _decoded(tmp_path / "fl", "/temperatures")
    errs = _decoded(tmp_path / "fl", "/errors/measured")
    state = _decoded(tmp_path / "fl", "/machine_state")
    assert temps[0].sensor_ids == [f"t{i}" for i in range(1, 17)]
    np.testing.assert_array_equal(np.array([m.temperatures_degc for m in temps]),
                                  np.column_stack([rec.columns[f"t{i}_c"][idx] for i in range(1, 17)]))
    assert errs[0].component_names == ["ch1", "ch2", "ch3", "ch4", "ch5"]
    assert all(m.source == 0 and list(m.units) == [0] * 5 for m in errs)
    np.testing.assert_array_equal(np.array([m.values for m in errs])[:, 0], rec.columns["ch1_um"][idx])
    assert state[0].spindle_names == ["spindle"]
    np.testing.assert_array_equal([m.spindle_speeds_rpm[0] for m in state], rec.columns["spindle_rpm"][idx])
    stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in temps]
    np.testing.assert_allclose(stamps, rec.time_s[idx])


def test_twin_inputs_are_named_as_machine_sim_names_them(tmp_path):
    csv = small_recording_csv(tmp_path / "r.csv", rows=12)
    rec = read_recording_csv(csv)
    cols = dict(rec.columns)
    cols["coolant_temp_degc"] = np.full(12, 21.5)
    cols["ambient_degc"] = np.full(12, 20.0)
    write_recording_csv(tmp_path / "r2.csv", rec.time_s, cols)
    res = csv_to_bag(tmp_path / "r2.csv", tmp_path / "bag", namespace="cell1", start_s=1000.0)
    assert res.unmapped == ["ambient_degc"]
    state = _decoded(tmp_path / "bag", "/cell1/machine_state")
    assert state[0].rotary_axis_names == ["C"] and state[0].coolant_temperature_degc == 21.5
    assert [bool(m.coolant_on) for m in state] == [bool(v > 0.5) for v in rec.columns["coolant_on"]]
    gt = _decoded(tmp_path / "bag", "/cell1/errors/ground_truth")
    assert gt[0].source == 2 and gt[0].model_kind == "twin" and list(gt[0].units) == [0, 1]
    assert all(math.isnan(u) for u in gt[0].uncertainties)
    assert gt[0].header.stamp.sec == 1000
    assert represented_inputs(["c_speed_rpm", "s1_rpm", "oil_on", "x_w", "weird"]) == (
        ["c_speed_rpm", "s1_rpm", "oil_on", "x_w"], ["weird"])


def test_bad_requests_name_the_option(tmp_path):
    csv = small_recording_csv(tmp_path / "r.csv", rows=8)
    cols = dict(read_recording_csv(csv).columns)
    cols["ambient_degc"] = np.zeros(8)
    write_recording_csv(tmp_path / "u.csv", np.arange(8.0), cols)
    for kwargs, text in (({"errors_as": "truth"}, "errors_as: 'truth'"), ({"every": 0}, "every: 0"),
                         ({"rows": (3, 3)}, "rows: 3:3"), ({"start_s": -1.0}, "start_s: -1.0"),
                         ({"temperatures_topic": "/abs"}, "temperatures_topic: '/abs'"),
                         ({"strict": True}, "'ambient_degc'")):
        with pytest.raises(CsvImportError, match=text):
            csv_to_bag(tmp_path / "u.csv", tmp_path / f"b{len(text)}", **kwargs)


def test_cli_reports_a_truncated_csv_and_keeps_the_rows_before(tmp_path):
    csv = small_recording_csv(tmp_path / "r.csv", rows=20)
    text = csv.read_text()
    csv.write_text(text[: text.rstrip("\n").rfind("\n") + 8])   # last line cut short
    p = subprocess.run([sys.executable, "-m", "thermal_comp.bags.import_csv_cli", str(csv), str(tmp_path / "bag"),
                        "--no-progress"], env=env(), capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "truncated" in p.stderr and "19 rows" in p.stdout
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,a_c\n0,1\n1,x\n")
    p = subprocess.run([sys.executable, "-m", "thermal_comp.bags.import_csv_cli", str(bad), str(tmp_path / "bag2"),
                        "--no-progress"], env=env(), capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "line 3: column 'a_c': 'x' is not a number" in p.stderr
    assert not (tmp_path / "bag2").exists()


def test_a_csv_without_time_column_is_imported_only_with_a_sample_period(tmp_path):
    csv = small_recording_csv(tmp_path / "r.csv", rows=12)
    untimed = tmp_path / "untimed.csv"
    untimed.write_text("\n".join(line.split(",", 1)[1] for line in csv.read_text().splitlines()) + "\n")
    cmd = [sys.executable, "-m", "thermal_comp.bags.import_csv_cli", str(untimed), "--no-progress"]
    p = subprocess.run([*cmd, str(tmp_path / "refused")], env=env(), capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "--sample-period-s" in p.stderr and not (tmp_path / "refused").exists()
    p = subprocess.run([*cmd, str(tmp_path / "bag"), "--sample-period-s", "30"], env=env(), capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    stamps = [m.stamp_ns * 1e-9 for m in read_bag(tmp_path / "bag").messages if m.topic.endswith("temperatures")]
    assert len(stamps) == 12 and stamps[-1] - stamps[0] == pytest.approx(11 * 30.0)
