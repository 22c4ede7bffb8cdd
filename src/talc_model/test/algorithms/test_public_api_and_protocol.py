"""talc_model's public API, the one streaming protocol of the adaptive models, one persistence
naming, and scikit-learn conventions of the batch estimators."""
from __future__ import annotations

import inspect
import json
import subprocess
import sys

import numpy as np
import pytest
from sklearn.base import BaseEstimator, clone

import talc_model
from talc_model import (AdaptiveModel, ArdGaussianProcess, ArxModel, ArxOrders, CharacteristicDiagram,
                        LaggedTemperatureModel, LoadDrivenProbing, OffsetModel, make_model)
from talc_model.adaptive_model import PROVIDER_MODULES

PROTOCOL = ["update_inputs", "predict", "probe_due", "add_measurement", "add_failed_measurement", "status",
            "to_state", "from_state"]


def test_every_public_name_imports_from_the_package():
    assert talc_model.__all__
    for name in talc_model.__all__:
        value = getattr(talc_model, name)
        assert getattr(value, "__module__", "talc_model.").startswith("talc_model."), name
    with pytest.raises(AttributeError, match="no attribute 'no_such_name'"):
        getattr(talc_model, "no_such_name")


def test_the_public_names_need_no_rclpy_and_the_talc_module_no_scikit_learn():
    code = ("import sys\nfrom talc_model import *\nimport talc_model\n"
            "assert all(n in globals() for n in talc_model.__all__)\nprint('rclpy' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"
    code = "import sys\nimport talc_model.talc.model\nprint('sklearn' in sys.modules)"
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


def _models():
    models = {kind: make_model(kind, {}) for kind in sorted(PROVIDER_MODULES)}
    models["talc+load_probing"] = LoadDrivenProbing(make_model("talc", {}))
    return models


@pytest.mark.parametrize("kind", sorted(PROVIDER_MODULES) + ["talc+load_probing"])
def test_every_adaptive_model_follows_the_protocol_exactly(kind):
    model = _models()[kind]
    assert isinstance(model, AdaptiveModel)
    for name in PROTOCOL:
        want = list(inspect.signature(getattr(AdaptiveModel, name)).parameters)
        got = list(inspect.signature(getattr(type(model), name)).parameters)
        assert got == want, f"{type(model).__name__}.{name}{got} differs from the protocol's {want}"
    back = type(model).from_state(json.loads(json.dumps(model.to_state())))
    assert back.to_state() == json.loads(json.dumps(model.to_state()))


@pytest.mark.parametrize("cls", [ArxModel, ArxOrders, ArdGaussianProcess, CharacteristicDiagram, OffsetModel,
                                 LoadDrivenProbing] + [type(m) for m in _models().values()])
def test_one_persistence_naming(cls):
    assert callable(getattr(cls, "to_state", None)) and callable(getattr(cls, "from_state", None))
    for other in ("as_dict", "from_dict", "save", "load", "state_dict", "get_state", "set_state"):
        assert not hasattr(cls, other), f"{cls.__name__}.{other}: persistence is to_state/from_state"


def _check_estimator(est: BaseEstimator, X: np.ndarray, y: np.ndarray) -> None:
    params = est.get_params()
    assert all(not k.endswith("_") for k in params)
    assert clone(est).get_params() == params
    assert est.fit(X, y) is est
    fitted = [k for k in vars(est) if k.endswith("_") and not k.startswith("_")]
    assert fitted and not set(fitted) & set(params)
    assert est.predict(X).shape == y.shape
    est.set_params(**params)


def test_batch_estimators_follow_scikit_learn_conventions():
    rng = np.random.default_rng(0)
    X = rng.uniform(0.0, 1.0, (80, 2))
    y = np.sin(3.0 * X[:, 0]) + X[:, 1]
    cd = CharacteristicDiagram(n_intervals=3, smoothing=1e-4)
    _check_estimator(cd, X, y)
    assert cd.fit(X, y, sample_weight=np.ones(80)) is cd
    _check_estimator(LaggedTemperatureModel(taus_s=(600.0,), alpha=1.0), X, y)
