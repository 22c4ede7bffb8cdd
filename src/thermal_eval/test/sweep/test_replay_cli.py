"""thermal-comp replay: a twin CSV through TALC, every JSON key written; bad parameters named."""
from __future__ import annotations

import json
import math
import pathlib

from thermal_eval.replay.cli import main as replay_main

TOP_KEYS = {"recording", "model", "config", "probe_noise", "components", "p99_lin_um", "p99_ang_um_per_m",
            "q_prod_pct", "probing_cycles", "failed_probing_cycles", "no_good_phases", "parameter_updates",
            "calibration_h", "compensation_steps", "duration_h", "final_phase", "replay_s"}
COMPONENTS = ["E_X0C", "E_Y0C", "E_Z0T", "E_R0T", "E_A0C", "E_B0C", "E_C0C"]


def test_replay_writes_every_key_and_a_plot(short_csv, tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = replay_main([str(short_csv), "--model", "talc", "--set", "preset=table_6_3_A",
                      "--set", "input_names=[ambient, ws_mwf, c_coolant_delta]", "--set", "cp_length_h=6",
                      "--json", str(out), "--no-progress"])
    assert rc == 0
    data = json.loads(out.read_text())
    assert TOP_KEYS <= set(data)
    assert list(data["components"]) == COMPONENTS
    for c, row in data["components"].items():
        assert {"p99", "rms", "p99_uncompensated", "rms_uncompensated", "unit"} <= set(row)
        assert row["unit"] == ("um/m" if c in ("E_A0C", "E_B0C", "E_C0C") else "um")
        assert row["p99"] is not None and row["p99"] >= 0
    assert data["probe_noise"] == {"linear_um": 0.25, "angular_um_per_m": 1.2, "resolution_um": 0.25, "seed": 0}
    assert data["config"]["cp_length_h"] == 6
    assert 6.0 <= data["calibration_h"] < 12.0 and data["final_phase"] in ("compensation", "no_good")
    # 6 h of 5-min probing (395 s period) costs about a quarter of the 6 h, less over 12 h
    assert 80.0 < data["q_prod_pct"] < 95.0 and data["probing_cycles"] >= 50
    lin = [data["components"][c]["p99"] for c in COMPONENTS[:4]]
    assert math.isclose(data["p99_lin_um"], sum(lin) / 4, rel_tol=1e-9)
    assert out.with_suffix(".png").stat().st_size > 0
    text = capsys.readouterr().out
    assert "P99 compensated" in text and "E_Y0C" in text


def test_replay_names_a_bad_key_and_writes_nothing(short_csv, tmp_path, capsys):
    out = tmp_path / "bad.json"
    assert replay_main([str(short_csv), "--model", "talc", "--set", "cp_lenght_h=6", "--json", str(out)]) == 2
    assert "cp_lenght_h" in capsys.readouterr().err
    assert replay_main([str(short_csv), "--model", "talc", "--set", "post_cp_interval_h=-2",
                        "--json", str(out)]) == 2
    assert "post_cp_interval_h" in capsys.readouterr().err
    assert replay_main([str(tmp_path / "missing.csv"), "--model", "talc", "--json", str(out)]) == 2
    assert "missing.csv" in capsys.readouterr().err
    assert not out.exists()


def test_replay_reads_a_bag(tmp_path):
    """The recorded regression bag of the twin's load case A (ground-truth errors on their topic)."""
    bag = pathlib.Path(__file__).resolve().parents[4] / "bags" / "nmv5000_load_case_A_24h"
    out = tmp_path / "bag.json"
    assert replay_main([str(bag), "--model", "talc", "--set", "cp_length_h=4", "--hours", "14",
                        "--set", "input_names=[ambient, ws_mwf, c_coolant_delta]",
                        "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert abs(data["duration_h"] - 14.0) < 0.05
    assert list(data["components"]) == COMPONENTS
    assert data["compensation_steps"] > 0 and data["probing_cycles"] > 0
    assert data["p99_lin_um"] is not None and data["p99_lin_um"] > 0
