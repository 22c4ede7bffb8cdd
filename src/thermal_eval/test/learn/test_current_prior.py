"""learn --current-prior: the adaptive half of the adoption test is against the prior running now
(online, after an adoption), not the type's; the report names it (path and sha256); a prior that
cannot be trusted or does not fit the run is refused in one line naming the option and value."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from talc_model.prior.talc import build_talc_prior, save_prior
from thermal_comp_common.recording_csv import Recording
from thermal_eval.learn import command
from thermal_eval.learn.adoption import Adoption
from thermal_eval.learn.cli import main as learn_main
from thermal_eval.learn.current import load_current
from thermal_eval.learn.probes import ProbeSet
from thermal_twin.machine.schema import load_machine, save_machine

CFG = {"component_names": ["E_X0C"], "angular_components": [], "input_names": ["amb"], "cp_length_h": 0.0,
       "post_cp_interval_h": 2.0, "na_max": 1, "nb_max": 2, "nb_max_final": 2, "type_model": "nmv5000"}


def _plant(seed: int) -> Recording:
    """A synthetic TALC training run: the error a first-order lag (3 h) of 3 x the ambient's delta."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 24 * 3600.0, 300.0)
    amb = 20 + sum(rng.uniform(0.5, 2) * np.sin(2 * np.pi * t / (rng.uniform(4, 20) * 3600) + rng.uniform(0, 6))
                   for _ in range(3))
    a, e = math.exp(-300.0 / (3 * 3600.0)), np.zeros_like(t)
    for k in range(1, t.size):
        e[k] = a * e[k - 1] + (1 - a) * 3.0 * (amb[k - 1] - amb[0])
    return Recording(t, {"amb_c": amb, "E_X0C": e}, source="synthetic")


@pytest.fixture(scope="module")
def small_prior(tmp_path_factory):
    d = tmp_path_factory.mktemp("current")
    path = save_prior(d / "prior.json", build_talc_prior([_plant(1), _plant(2)], CFG, machine="nmv5000", nb_max=2))
    (d / "cfg.yaml").write_text(yaml.safe_dump(CFG))
    return d, path


def _refused(capsys, argv) -> str:
    assert learn_main(["rec.csv", "--twin", "nmv5000", "--out", "never", "--quiet", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err
    return err


def test_a_current_prior_that_cannot_be_used_is_refused_in_one_line(small_prior, tmp_path, capsys):
    d, prior = small_prior
    missing = tmp_path / "missing.json"
    assert _refused(capsys, ["--current-prior", str(missing)]) == \
        f"thermal-comp learn: --current-prior {missing}: cannot read it (No such file or directory)"
    (tmp_path / "bad.json").write_text("{")
    assert _refused(capsys, ["--current-prior", str(tmp_path / "bad.json")]).startswith(
        f"thermal-comp learn: --current-prior {tmp_path / 'bad.json'}: prior")
    doc = json.loads(prior.read_text())
    doc["machine"] = "other"
    (tmp_path / "changed.json").write_text(json.dumps(doc))
    assert "does not match the content" in _refused(capsys, ["--current-prior", str(tmp_path / "changed.json")])
    # its soft-sensor twin is not the --twin learn starts from
    twin = tmp_path / "unit_twin.yaml"
    save_machine(load_machine("nmv5000"), twin)
    err = _refused(capsys, ["--current-prior", str(prior), "--twin", str(twin)])
    assert f"--current-prior {prior}: its soft-sensor twin 'type_model' is 'nmv5000', not --twin" in err
    # the shipped configuration's inputs are not this prior's (its config must be given)
    assert f"--current-prior {prior}: prior: 'input_names' are ['amb']" in _refused(capsys, ["--current-prior", str(prior)])
    (tmp_path / "list.yaml").write_text("[1, 2]")
    assert _refused(capsys, ["--current-prior", str(prior), "--current-config", str(tmp_path / "list.yaml")]) == \
        f"thermal-comp learn: --current-config {tmp_path / 'list.yaml'}: must hold a mapping, got list"
    (tmp_path / "other.yaml").write_text(yaml.safe_dump(dict(CFG, type_model=str(twin))))
    assert "(the prior was built on another twin's soft sensors)" in _refused(
        capsys, ["--current-prior", str(prior), "--current-config", str(tmp_path / "other.yaml")])
    assert "--current-config x.yaml: needs --current-prior" in _refused(capsys, ["--current-config", "x.yaml"])
    assert "no adaptive test with --no-prior" in _refused(capsys, ["--current-prior", str(prior), "--no-prior"])


def test_the_adaptive_test_is_against_the_given_prior_never_the_type_cache(small_prior, tmp_path, monkeypatch):
    d, prior = small_prior
    current = load_current(str(prior), str(d / "cfg.yaml"), "nmv5000", load_machine("nmv5000"))
    assert current.sha256 == json.loads(prior.read_text())["sha256"] and current.config == CFG
    monkeypatch.setattr(command, "cached_prior", lambda *a, **k: pytest.fail("the type's prior was used"))
    ref, models = command._prior_models(load_machine("nmv5000"), tmp_path / "u.yaml", tmp_path, print,
                                        unit=False, current=current)
    assert ref is current and list(models) == ["current prior"] and models["current prior"][1] is current.prior
    assert ref.as_dict() == {"prior": str(prior), "sha256": current.sha256, "model_config": str(d / "cfg.yaml"),
                             "source": "given", "type_model": "nmv5000"}


def test_a_learned_prior_must_beat_the_reference_it_is_given(tmp_path):
    t = np.arange(5) * 3600.0
    v = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    sub = ProbeSet(t, {"E_X0C": v}, {"E_X0C": 0.25})
    mask = np.array([False, False, True, True, True])
    open_loop = Adoption(True, "better")
    preds = {"adaptive, type prior": {"E_X0C": v + 2.0}, "adaptive, current prior": {"E_X0C": v + 0.05},
             "adaptive, unit prior": {"E_X0C": v + 0.5}}
    comps = {"unit prior": ["E_X0C"], "current prior": ["E_X0C"], "type prior": ["E_X0C"]}
    for name in ("prior.json", "model_config.yaml"):
        (tmp_path / name).write_text("")
    # better than the type's prior, not than the one running now
    assert command._adaptive_check(open_loop, sub, preds, mask, tmp_path, "type prior", comps).adopt
    kept = command._adaptive_check(open_loop, sub, preds, mask, tmp_path, "current prior", comps)
    assert not kept.adopt and "against the current prior is worse beyond the probe uncertainty" in kept.reason
    assert not (tmp_path / "prior.json").exists()        # a prior not adopted is not left behind
    other = command._adaptive_check(open_loop, sub, preds, mask, tmp_path, "current prior",
                                    dict(comps, **{"unit prior": ["E_X0C", "E_Y0C"]}))
    assert not other.adopt and "of other components" in other.reason
