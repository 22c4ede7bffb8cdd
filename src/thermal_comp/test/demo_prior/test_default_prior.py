"""The demo starts from the machine type's prior by default (cached), says when none applies,
and prints the no-prior run of the same plant beside it only when asked."""
import pathlib

import pytest

from talc_model.prior.talc import build_talc_prior, load_prior
from talc_model.prior.agp import AgpPriorModel, build_agp_prior
from talc_model.prior.dispatch import model_from_prior
from thermal_comp.demo import cli as demo_cli
from thermal_comp.demo import run as demo_run
from thermal_comp.prior import build as prior_build
from thermal_comp.prior import programmes as prior_programmes
from thermal_comp.demo.cell import DemoConfig, build_cell
from thermal_comp.demo.summary import print_prior_gain, prior_gain
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

CONFIG = {"input_names": ["ambient", "ws_mwf", "c_coolant_delta"]}


@pytest.fixture
def counted_build(monkeypatch):
    """prior_build.build_prior on the nominal runs (the real fit; TALC: fewer programmes and orders;
    AGP: 3 h of each programme, 60 points), counting calls."""
    calls = []

    def build(machine, config, scenarios, seed_base=101, na_max=1, nb_max=8, progress=None, kind="talc"):
        calls.append((machine, tuple(scenarios), kind))
        hours = 3.0 if kind == "agp" else None
        recs = [simulate(machine, make_timeline(machine, s, seed=seed_base + i, hours=hours),
                         seed=seed_base + i).to_recording() for i, s in enumerate(scenarios)]
        if kind == "agp":
            return build_agp_prior(recs, config, machine=machine, max_points=60)
        return build_talc_prior(recs, config, machine=machine, na_max=na_max, nb_max=3)
    monkeypatch.setattr(prior_build, "build_prior", build)
    return calls


def test_prior_is_built_once_then_read_from_the_cache(tmp_path, counted_build):
    scen = ["load-case-A", "load-case-D", "load-case-B"]
    p1, built1 = prior_build.cached_prior("nmv5000", CONFIG, scen, cache_dir=tmp_path)
    p2, built2 = prior_build.cached_prior("nmv5000", CONFIG, scen, cache_dir=tmp_path)
    assert (built1, built2) == (True, False) and p1 == p2 and len(counted_build) == 1
    assert load_prior(p2)["machine"] == "nmv5000"
    # another configuration is another prior
    p3, built3 = prior_build.cached_prior("nmv5000", {**CONFIG, "nb_max": 4}, scen, cache_dir=tmp_path)
    assert built3 and p3 != p1 and len(counted_build) == 2
    # a damaged cache entry is rebuilt, not trusted
    p1.write_text("{not json")
    _, built4 = prior_build.cached_prior("nmv5000", CONFIG, scen, cache_dir=tmp_path)
    assert built4 and load_prior(p1)["machine"] == "nmv5000"


def test_default_is_the_prior_and_no_prior_is_asked_for():
    ap = demo_cli._parser()
    assert ap.parse_args([]).prior == demo_cli.DEFAULT_PRIOR
    assert ap.parse_args(["--prior"]).prior == demo_cli.BUILD_PRIOR
    assert ap.parse_args(["--prior", "x.json"]).prior == "x.json"
    assert ap.parse_args(["--no-prior"]).prior is None
    assert not ap.parse_args([]).compare_no_prior
    with pytest.raises(SystemExit):
        ap.parse_args(["--prior", "x.json", "--no-prior"])


def test_no_default_prior_where_none_applies(tmp_path, capsys):
    assert demo_run._no_default_prior_reason(DemoConfig(scenario="talc-178h-dry")) is None
    assert "training programmes" in demo_run._no_default_prior_reason(DemoConfig(scenario="load-case-A"))
    assert demo_run._no_default_prior_reason(DemoConfig(machine="swiss-lathe", scenario="lathe-random-speed")) is None
    assert "training programmes" in demo_run._no_default_prior_reason(
        DemoConfig(machine="swiss-lathe", scenario="lathe-oil-steps"))
    with pytest.raises(demo_run.DemoError, match="training programmes"):
        demo_run._build_prior(DemoConfig(scenario="load-case-A", out_dir=tmp_path))
    assert demo_cli.main(["--no-prior", "--compare-no-prior", "--out", str(tmp_path)]) == 1
    assert "cannot go with --no-prior" in capsys.readouterr().err


def test_build_prior_copies_the_cached_prior_into_the_run(tmp_path, monkeypatch, counted_build):
    monkeypatch.setenv("THERMAL_COMP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setitem(prior_programmes.TRAINING_SCENARIOS["talc"], "nmv5000", ["load-case-A", "load-case-D", "load-case-B"])
    cfg = DemoConfig(scenario="talc-178h-dry", out_dir=tmp_path / "run")
    path = demo_run._build_prior(cfg)
    assert path == (tmp_path / "run" / "prior.json").resolve() and load_prior(path)["machine"] == "nmv5000"
    demo_run._build_prior(DemoConfig(scenario="talc-178h-dry", out_dir=tmp_path / "run2"))
    assert len(counted_build) == 1                                   # the second run used the cache
    assert pathlib.Path(tmp_path / "cache" / "priors").is_dir()


def test_prior_gain_table(capsys):
    def summary(p99, q, ng):
        return {"machine": "nmv5000", "plant": "nmv5000 unit #1", "scenario": "talc-178h-dry",
                "p99_compensated_whole_run": {"E_Y0C": p99, "E_C0C": 2 * p99}, "q_prod_pct": q,
                "p99_lin_whole_run_um": p99, "no_good_phases": ng,
                "thesis": {"p99_compensated": {"E_Y0C": 4.9, "E_C0C": 7.0}}}
    g = prior_gain(summary(2.0, 98.5, 0), summary(6.0, 96.9, 7))
    assert g["components"]["E_Y0C"] == {"with_prior": 2.0, "no_prior": 6.0, "thesis": 4.9}
    assert g["q_prod_pct"] == [98.5, 96.9] and g["no_good_phases"] == [0, 7]
    print_prior_gain(summary(2.0, 98.5, 0), summary(6.0, 96.9, 7))
    out = capsys.readouterr().out
    assert "with prior" in out and "no prior" in out and "4.9" in out


def test_lathe_demo_defaults_to_the_agp_prior_of_its_type(tmp_path, monkeypatch, counted_build, capsys):
    """swiss-lathe: the default run builds (once) and uses the AGP prior of the nominal lathe,
    says so, and hands it to the model node, which starts the AGP from it."""
    monkeypatch.setenv("THERMAL_COMP_CACHE", str(tmp_path / "cache"))
    cfg = DemoConfig(machine="swiss-lathe", scenario="lathe-random-speed", out_dir=tmp_path / "run")
    path = demo_run._build_prior(cfg)
    prior = load_prior(path)
    assert prior["model_kind"] == "agp" and prior["machine"] == "swiss-lathe"
    assert counted_build == [("swiss-lathe", tuple(prior_programmes.TRAINING_SCENARIOS["agp"]["swiss_lathe"]), "agp")]
    assert "lathe-random-speed" not in counted_build[0][1]                # never the demo's run
    out = capsys.readouterr().out
    assert "built AGP prior of the machine type swiss-lathe" in out
    demo_run._build_prior(DemoConfig(machine="swiss-lathe", scenario="lathe-random-speed", out_dir=tmp_path / "r2"))
    assert len(counted_build) == 1 and "cached AGP prior" in capsys.readouterr().out
    cfg.prior = str(path)
    model = {n["name"]: n for n in build_cell(cfg, 42, None, False)["nodes"]}["model"]["parameters"]
    assert model["model_kind"] == "agp" and model["prior_path"] == str(path)
    assert isinstance(model_from_prior("agp", {}, load_prior(model["prior_path"])), AgpPriorModel)
    # the cache keeps one file per model kind: an AGP prior is never read back as another kind's
    cached = list((tmp_path / "cache" / "priors").glob("swiss-lathe-agp-*.json"))
    assert len(cached) == 1
