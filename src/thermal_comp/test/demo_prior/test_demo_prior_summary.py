"""The demo's summary: which plant and prior, the whole-run P99 and probe-and-hold beside it;
the demo cell runs a machine instance and passes the prior to the model node."""
import pathlib

import numpy as np
import yaml

from thermal_comp.demo.cell import DemoConfig, build_cell, plant_label
from thermal_comp.demo.series import DemoSeries
from thermal_comp.demo.summary import print_table, summarise


def _series(hours=48.0):
    t = np.arange(0.0, hours * 3600.0, 300.0)
    true = {"E_Y0C": 10 * np.sin(t / 20000.0), "E_C0C": 5 * np.sin(t / 30000.0)}
    pred = {c: v + 0.3 for c, v in true.items()}
    return DemoSeries(components=list(true), units={"E_Y0C": "um", "E_C0C": "um/m"}, t_true=t, true=true,
                      t_pred=t - 1.0, predicted=pred, std={c: np.zeros_like(t) for c in true},
                      probe_times_s=[], t_applied=np.array([]), applied={},
                      status={"q_prod_pct": 97.0, "model_kind": "talc"}, phases=[(0.0, 1)],
                      limit_hits=0, offsets_published=t.size)


def test_summary_has_plant_prior_whole_run_and_probe_and_hold(tmp_path, capsys):
    cfg = DemoConfig(out_dir=tmp_path, unit=3, prior="p.json", scenario="talc-178h-dry")
    s = summarise(_series(), cfg, None)
    assert s["plant"] == "nmv5000 unit #3" and s["prior"] == "p.json"
    assert 0.2 < s["p99_compensated_whole_run"]["E_Y0C"] < 0.4          # the constant 0.3 offset
    base = s["probe_and_hold"]
    assert base["interval_h"] == round(95.0 / 0.03 / 3600.0, 3)
    # holding a sine of amplitude 10 over 0.88 h leaves more than the model's 0.3
    assert base["p99"]["E_Y0C"] > 0.3
    print_table(s)
    out = capsys.readouterr().out
    assert "probe-and-hold" in out and "nmv5000 unit #3" in out


def test_cell_runs_the_instance_and_hands_the_prior_to_the_model(tmp_path):
    cfg = DemoConfig(out_dir=tmp_path, unit=2, prior=str(tmp_path / "prior.json"), scenario="talc-178h-dry")
    cell = build_cell(cfg, 42, None, False)
    nodes = {n["name"]: n for n in cell["nodes"]}
    machine = pathlib.Path(nodes["machine_sim"]["parameters"]["machine"])
    assert machine.is_file() and "unit #2" in yaml.safe_load(machine.read_text())["description"]
    assert nodes["model"]["parameters"]["prior_path"] == str(tmp_path / "prior.json")
    nominal = build_cell(DemoConfig(out_dir=tmp_path, scenario="talc-178h-dry"), 42, None, False)
    assert {n["name"]: n for n in nominal["nodes"]}["machine_sim"]["parameters"]["machine"] == "nmv5000"
    assert plant_label(DemoConfig()) == "nmv5000 (nominal)"
