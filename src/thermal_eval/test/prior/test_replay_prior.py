"""`thermal-comp replay --prior` and probe-and-hold printed beside every replay."""
import json

from talc_model.prior.talc import build_talc_prior, save_prior
from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.replay.cli import main
from thermal_twin.machine.instance import machine_instance
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

CFG = ["--set", "input_names=[ambient, ws_mwf, c_coolant_delta]", "--set", "na_max=1", "--set", "nb_max=3",
       "--set", "nb_max_final=3"]


def _csv(path, machine, scenario, seed, hours):
    r = simulate(machine, make_timeline("nmv5000", scenario, hours=hours, seed=seed, step_s=300.0), seed=seed)
    write_recording_csv(path, r.time_s, r.columns())
    return r.to_recording()


def test_replay_with_prior_prints_probe_and_hold(tmp_path, capsys):
    recs = [_csv(tmp_path / f"n{i}.csv", "nmv5000", s, 101 + i, None)
            for i, s in enumerate(["load-case-A", "load-case-D", "load-case-B"])]
    prior = build_talc_prior(recs, {"input_names": ["ambient", "ws_mwf", "c_coolant_delta"]}, nb_max=3)
    save_prior(tmp_path / "prior.json", prior)
    _csv(tmp_path / "run.csv", machine_instance("nmv5000", 1), "talc-178h-dry", 0, 24.0)
    rc = main([str(tmp_path / "run.csv"), "--model", "talc", *CFG, "--prior", str(tmp_path / "prior.json"),
               "--json", str(tmp_path / "out.json"), "--no-progress"])
    assert rc == 0
    out = json.loads((tmp_path / "out.json").read_text())
    assert out["calibration_h"] == 0.0                  # the prior compensates from the start
    whole = out["probe_and_hold"]["whole_run"]
    assert whole["probe_and_hold"]["q_prod_pct"] == out["q_prod_pct"]
    assert whole["p99_lin_ratio"] == whole["model"]["p99_lin_um"] / whole["probe_and_hold"]["p99_lin_um"]
    assert "probe-and-hold P99" in capsys.readouterr().out


def test_an_unreadable_prior_is_refused_in_one_line(tmp_path, capsys):
    """TALC and the AGP take a prior (talc_model.prior.dispatch.model_from_prior picks the kind);
    a prior file that cannot be read stops the replay with one line naming it, and writes nothing."""
    _csv(tmp_path / "run.csv", "nmv5000", "load-case-A", 0, 6.0)
    rc = main([str(tmp_path / "run.csv"), "--model", "agp", "--prior", "x.json", "--json", str(tmp_path / "o.json")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "prior 'x.json'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.json").exists()
