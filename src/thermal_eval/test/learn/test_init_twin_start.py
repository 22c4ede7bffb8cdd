"""A ``twin init`` folder is a complete starting point: ``prior`` and ``learn`` take its twin with
the configuration written beside it (its own nodes as soft sensors), never the shipped
configuration or the cached prior of a preset that shares the twin's name."""
from __future__ import annotations

import pathlib

import pytest
import yaml

from talc_model.prior.integrity import prior_identity
from thermal_comp.prior import build
from thermal_comp.prior.build import _cache_key, cached_prior, default_config, training_scenarios
from thermal_eval.learn import command
from thermal_eval.twin_init.units_case import DESCRIPTION
from thermal_twin.identify import MODEL_CONFIG, load_description, own_model_config
from thermal_twin.identify.command import model_config
from thermal_twin.identify.structure import starting_spec
from thermal_twin.machine.schema import load_machine, save_machine
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate


def _init_folder(folder: pathlib.Path) -> pathlib.Path:
    """What twin init writes (twin.yaml + model_config.yaml) for a twin named like the preset
    ``nmv5000``, from its starting structure (every error on every body: no fit, the test is
    about which files are read)."""
    d = load_description(str(DESCRIPTION))
    rec = simulate(load_machine("nmv5000"), make_timeline("nmv5000", "talc-178h-dry", hours=4, seed=3),
                   seed=3).to_recording()
    spec = starting_spec(d, rec, hidden=1)
    for e in spec["errors"].values():
        e["terms"] = {n: 0.5 for n in e["terms"]}
    folder.mkdir(parents=True)
    path = folder / "twin.yaml"
    save_machine(spec, path)
    (folder / MODEL_CONFIG).write_text(yaml.safe_dump(model_config(d, load_machine(str(path)), path)))
    return path


@pytest.fixture()
def init_twin(tmp_path) -> pathlib.Path:
    return _init_folder(tmp_path / "init")


def test_the_init_folder_configuration_is_the_twins_not_the_namesake_presets(init_twin, tmp_path):
    cfg = default_config(str(init_twin), "talc")
    assert cfg["type_model"] == str(init_twin.resolve())
    assert all(n.startswith("twin:") for n in cfg["type_input_names"])
    preset = default_config("nmv5000", "talc")
    assert cfg["type_input_names"] != preset["type_input_names"]
    # the cache key of the init twin's prior is not the preset's (same name, other twin)
    scen = training_scenarios("talc", "nmv5000")
    assert _cache_key(str(init_twin), cfg, scen, 0, 1, 8) != _cache_key("nmv5000", preset, scen, 0, 1, 8)
    # a twin edited in place is another prior
    before = _cache_key(str(init_twin), cfg, scen, 0, 1, 8)
    init_twin.write_text(init_twin.read_text().replace("capacity: 100000.0", "capacity: 120000.0", 1))
    assert _cache_key(str(init_twin), cfg, scen, 0, 1, 8) != before


def test_a_configuration_for_another_twin_or_no_file_is_not_taken(init_twin, tmp_path):
    other = tmp_path / "other" / "twin.yaml"
    other.parent.mkdir()
    other.write_text(init_twin.read_text())
    assert own_model_config(other) is None                       # no configuration beside it
    (other.parent / MODEL_CONFIG).write_text((init_twin.parent / MODEL_CONFIG).read_text())
    assert own_model_config(other) is None                       # beside it, but naming the first twin
    assert own_model_config("nmv5000") is None
    (other.parent / MODEL_CONFIG).write_text("- a list\n")
    with pytest.raises(ValueError, match="model_config.yaml: must hold a mapping, got list"):
        own_model_config(other)


def test_a_moved_init_folder_keeps_its_configuration(init_twin, tmp_path):
    moved = tmp_path / "moved"
    init_twin.parent.rename(moved)
    cfg = own_model_config(moved / "twin.yaml")
    assert cfg is not None and cfg["type_model"] == str((moved / "twin.yaml").resolve())


def test_the_prior_cache_file_of_a_twin_file_stays_in_the_cache(init_twin, tmp_path, monkeypatch):
    monkeypatch.setattr(build, "build_prior", lambda *a, **k: {"fake": True})
    monkeypatch.setattr(build, "save_prior", lambda p, prior: pathlib.Path(p).write_text("{}"))
    cache = tmp_path / "cache"
    path, built = cached_prior(str(init_twin), default_config(str(init_twin), "talc"), ["x"], cache_dir=cache)
    assert built and path.parent == cache and path.name.startswith("nmv5000-talc-")


@pytest.mark.slow
def test_learn_tests_against_the_init_twins_own_prior_and_builds_the_unit_prior_with_its_config(
        init_twin, tmp_path, monkeypatch):
    monkeypatch.setenv("THERMAL_COMP_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "learned"
    out.mkdir()
    unit = out / "unit_twin.yaml"
    unit.write_text(init_twin.read_text())
    own = own_model_config(init_twin)
    current, models = command._prior_models(load_machine(str(init_twin)), unit, out, lambda m: None)
    assert current.source == "type" and current.config["type_model"] == str(init_twin.resolve())
    assert prior_identity(current.prior)["type_model"] == str(init_twin.resolve())
    assert pathlib.Path(current.path).parent == tmp_path / "cache" / "priors"
    unit_cfg, unit_prior = models["unit prior"]
    assert unit_cfg["type_model"] == str(unit.resolve())
    assert prior_identity(unit_prior)["type_model"] == str(unit.resolve())
    assert unit_cfg["type_input_names"] == own["type_input_names"]
    written = yaml.safe_load((out / "model_config.yaml").read_text())
    assert written == unit_cfg
