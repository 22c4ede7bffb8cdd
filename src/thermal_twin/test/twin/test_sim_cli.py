"""`thermal-comp sim`: CSV in the shared recording format; clear errors."""
from __future__ import annotations

import numpy as np

from thermal_comp_common.recording_csv import read_recording_csv
from thermal_twin.sim.cli import main


def test_sim_writes_a_recording_csv(tmp_path):
    out = tmp_path / "dry.csv"
    assert main(["--machine", "nmv5000", "--scenario", "talc-178h-dry", "--hours", "6", "--seed", "3",
                 "--csv", str(out), "--plot", str(tmp_path / "dry.png"), "--quiet"]) == 0
    assert (tmp_path / "dry.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rec = read_recording_csv(out)
    assert rec.names("error") == ["E_X0C", "E_Y0C", "E_Z0T", "E_R0T", "E_A0C", "E_B0C", "E_C0C"]
    assert rec.names("sensor") == ["ambient_c", "ws_mwf_c", "c_coolant_delta_c", "c_motor_internal_c"]
    assert rec.names("input") == ["c_speed_rpm", "coolant_on", "coolant_temp_degc", "ambient_degc"]
    assert rec.time_s[-1] == 6 * 3600.0 and np.all(np.diff(rec.time_s) == 60.0)
    # 1 degC motor sensor
    assert np.all(rec.columns["c_motor_internal_c"] == np.round(rec.columns["c_motor_internal_c"]))


def test_sim_rejects_bad_arguments_with_a_message(tmp_path, capsys):
    assert main(["--machine", "nmv5000", "--scenario", "lathe-test-piece", "--csv", str(tmp_path / "x.csv"),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "does not fit machine 'nmv5000'" in err and "talc-178h-dry" in err
    assert main(["--machine", "lathe", "--scenario", "x", "--csv", str(tmp_path / "x.csv")]) == 2
    assert "not a preset" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_sim_accepts_an_edited_machine_file(tmp_path):
    from thermal_twin.machine.schema import load_machine, save_machine
    d = load_machine("swiss-lathe").to_dict()
    d["sensors"]["ambient"]["bias"] = 0.5
    save_machine(d, tmp_path / "lathe.yaml")
    assert main(["--machine", str(tmp_path / "lathe.yaml"), "--scenario", "lathe-test-piece", "--hours", "1",
                 "--csv", str(tmp_path / "l.csv"), "--quiet"]) == 0
    assert "GB_X_um" in read_recording_csv(tmp_path / "l.csv").columns
