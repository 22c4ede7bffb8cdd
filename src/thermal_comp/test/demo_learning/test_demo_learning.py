"""The demo with a plant file and the online learner: the cell runs the plant and a learner that
learns from the recorder's bag on the type's twin, the model node audits into the same file; the
table splits the run at the first swap the model node audited and scores each side against
probe-and-hold; a plant of another type or a broken file is refused in one line."""
import json
import pathlib

import numpy as np
import pytest

from thermal_comp.demo.cell import AUDIT, DemoConfig, DemoError, build_cell, plant_label
from thermal_comp.demo.learning import adoption_instant, learning_summary, print_learning, split_at
from thermal_comp.demo.run import check_plant
from thermal_comp.demo.series import DemoSeries
from thermal_comp.demo.summary import compensation_in_effect

PLANT = pathlib.Path(__file__).resolve().parents[4] / "config" / "plants" / "nmv5000_unit13_links.yaml"


def _series(hours=48.0, t_swap=24 * 3600.0):
    """A model 2 um off before the swap and 0.2 um off after it."""
    t = np.arange(0.0, hours * 3600.0, 300.0)
    true = {"E_Y0C": 10 * np.sin(t / 20000.0), "E_C0C": 5 * np.sin(t / 30000.0)}
    pred = {c: v + np.where(t <= t_swap, 2.0, 0.2) for c, v in true.items()}
    return DemoSeries(components=list(true), units={"E_Y0C": "um", "E_C0C": "um/m"}, t_true=t + 1.0, true=true,
                      t_pred=t, predicted=pred, std={c: np.zeros_like(t) for c in true},
                      probe_times_s=[], t_applied=np.array([]), applied={},
                      status={"q_prod_pct": 97.0, "model_kind": "talc"}, phases=[(0.0, 1)],
                      limit_hits=0, offsets_published=t.size)


def test_the_cell_runs_the_plant_file_and_the_learner(tmp_path):
    cfg = DemoConfig(out_dir=tmp_path, plant=str(PLANT), prior=str(tmp_path / "prior.json"), learn_every_h=24.0,
                     scenario="talc-178h-dry")
    nodes = {n["name"]: n for n in build_cell(cfg, 42, None, False)["nodes"]}
    assert nodes["machine_sim"]["parameters"]["machine"] == str(PLANT)
    learner = nodes["learner"]["parameters"]
    assert learner["recording"] == str(tmp_path / "bag") and learner["twin"] == "nmv5000"
    assert learner["learn_every_h"] == 24.0 and learner["prior_path"] == str(tmp_path / "prior.json")
    assert learner["audit_path"] == nodes["model"]["parameters"]["audit_path"] == str(tmp_path / AUDIT)
    assert nodes["model"]["parameters"]["online_learning"] is True
    plain = {n["name"]: n for n in build_cell(DemoConfig(out_dir=tmp_path, scenario="talc-178h-dry"),
                                              42, None, False)["nodes"]}
    assert "learner" not in plain and not plain["model"]["parameters"].get("online_learning", False)
    assert plant_label(cfg) == "nmv5000 plant nmv5000_unit13_links.yaml"
    check_plant(cfg)


def test_a_plant_of_another_type_or_no_machine_is_refused(tmp_path):
    with pytest.raises(DemoError, match=r"a machine of type 'nmv5000', the demo runs 'swiss-lathe'"):
        check_plant(DemoConfig(machine="swiss-lathe", plant=str(PLANT)))
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [\n")
    with pytest.raises(DemoError, match=r"--plant .*bad.yaml"):
        check_plant(DemoConfig(plant=str(bad)))


def test_the_table_splits_at_the_first_swap_and_scores_both_sides(tmp_path, capsys):
    s = _series()
    lines = [{"event": "adoption sent", "source": "learner", "model_time_s": 20 * 3600.0, "reason": "sent"},
             {"event": "swapped", "source": "model node", "model_time_s": 24 * 3600.0, "reason": "in use"},
             {"event": "swapped", "source": "model node", "model_time_s": 40 * 3600.0, "reason": "again"}]
    (tmp_path / AUDIT).write_text("".join(json.dumps(ln) + "\n" for ln in lines))
    assert adoption_instant(lines) == 24 * 3600.0 and adoption_instant(lines[:1]) is None
    res = learning_summary(s, compensation_in_effect(s), 97.0, tmp_path, seed=0)
    assert res["adopted_at_h"] == 24.0 and [ln["event"] for ln in res["audit"]] == [ln["event"] for ln in lines]
    before, after = res["before"], res["after"]
    assert before["p99"]["E_Y0C"] == pytest.approx(2.0, abs=1e-6) and after["p99"]["E_Y0C"] == pytest.approx(0.2, abs=1e-6)
    assert before["window_h"][1] <= 24.0 <= after["window_h"][0]
    assert after["ratio"] == pytest.approx(0.2 / after["probe_and_hold"]["p99_lin_um"], rel=1e-2)
    assert split_at(s, compensation_in_effect(s), 97.0, 1e9, 0)["after"] is None
    print_learning({"learning": res, "machine": "nmv5000", "q_prod_pct": 97.0})
    out = capsys.readouterr().out
    assert "swapped in at 24 h" in out and "ratio to probe-and-hold" in out


def test_the_docs_table_is_generated_from_the_summary(tmp_path):
    from thermal_comp.demo.learning import markdown
    s = _series()
    res = split_at(s, compensation_in_effect(s), 97.0, 24 * 3600.0, 0)
    control = split_at(s, compensation_in_effect(s), 97.0, 24 * 3600.0, 1)
    text = markdown({"learning": {**res, "adopted_at_h": 24.0}}, control)
    rows = text.splitlines()
    assert rows[0].startswith("| error | before: 0-23.92 h |") and "control after" in rows[0]
    assert rows[2].startswith("| E_Y0C | 2.00 |")
    assert f"**{res['after']['ratio']:.3f}**" in rows[-3] and rows[-1].startswith("Control before the same instant")
