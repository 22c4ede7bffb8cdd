"""Priors for the online learner's tests: a run on the type's twin (``type_model`` nmv5000) and a
learned unit whose soft-sensor twin is another file, both TALC priors of a synthetic plant (the
learned one of a plant with a larger gain), built once per session."""
import json
import pathlib
import sys

import pytest
import yaml

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "prior"))
from test_prior_model import CFG, _plant  # noqa: E402  (the prior tests' synthetic plant)


@pytest.fixture(scope="session")
def priors(tmp_path_factory):
    from talc_model.prior.talc import build_talc_prior, save_prior
    from thermal_twin.machine.schema import load_machine, save_machine

    d = tmp_path_factory.mktemp("online_priors")
    twin = d / "unit_twin.yaml"
    save_machine(load_machine("nmv5000"), twin)
    run_cfg = dict(CFG, type_model="nmv5000")
    unit_cfg = dict(CFG, type_model=str(twin))
    type_prior = build_talc_prior([_plant(1), _plant(2), _plant(3)], run_cfg, machine="synthetic", nb_max=2)
    unit_prior = build_talc_prior([_plant(1, gain=4.0), _plant(2, gain=4.0), _plant(3, gain=4.0)], unit_cfg,
                                  machine="synthetic", nb_max=2)
    (d / "run_config.yaml").write_text(yaml.safe_dump(run_cfg))
    (d / "unit_config.yaml").write_text(yaml.safe_dump(unit_cfg))
    (d / "report.json").write_text(json.dumps({"train_h": 38.4, "recording_h": 48.0, "wall_s": {"calibration": 1.0},
                                               "adoption": {"adopt": True, "reason": "better", "validation_probes": 5,
                                                            "validation_rmse": {"E_X0C": {"type": 2.0, "unit": 0.4}}}}))
    return {"dir": d, "run_cfg": run_cfg, "unit_cfg": unit_cfg,
            "type_prior": save_prior(d / "type_prior.json", type_prior),
            "unit_prior": save_prior(d / "unit_prior.json", unit_prior),
            "run_config": d / "run_config.yaml", "unit_config": d / "unit_config.yaml", "report": d / "report.json",
            "plant": _plant(11, hours=30.0, gain=4.0)}
