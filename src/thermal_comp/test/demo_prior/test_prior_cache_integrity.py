"""The prior cache's key hashes the inputs, not the file: a cache file that was changed (hash),
re-hashed with diverging ARX models, or is of another machine is rebuilt with a one-line warning."""
import json
import math

import numpy as np
import pytest

from talc_model.prior.integrity import check_prior, stamped
from talc_model.prior.talc import build_talc_prior, load_prior
from thermal_comp.prior import build as prior_build
from thermal_comp_common.recording_csv import Recording

CFG = {"component_names": ["E_X0C"], "angular_components": [], "input_names": ["amb"],
       "cp_length_h": 0.0, "na_max": 1, "nb_max": 2, "nb_max_final": 2}
SCEN = ["load-case-A", "load-case-D", "load-case-B"]


def _plant(seed: int) -> Recording:
    """A first-order lag (tau 3 h, gain 3) of an ambient that wanders (seeded)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 24 * 3600.0, 300.0)
    amb = 20 + sum(rng.uniform(0.5, 2) * np.sin(2 * np.pi * t / (rng.uniform(4, 30) * 3600) + rng.uniform(0, 6))
                   for _ in range(3))
    a = math.exp(-300.0 / (3 * 3600.0))
    e = np.zeros_like(t)
    for k in range(1, t.size):
        e[k] = a * e[k - 1] + (1 - a) * 3.0 * (amb[k - 1] - amb[0])
    return Recording(t, {"amb_c": amb, "E_X0C": e}, source="synthetic")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """cached_prior with a small synthetic TALC prior of 'nmv5000' as the build (counted)."""
    calls = []

    def build(machine, config, scenarios, seed_base=101, na_max=1, nb_max=8, progress=None, kind="talc"):
        calls.append(machine)
        return build_talc_prior([_plant(i) for i in range(len(scenarios))], config, machine=machine, nb_max=2)
    monkeypatch.setattr(prior_build, "build_prior", build)

    def get():
        return prior_build.cached_prior("nmv5000", CFG, SCEN, cache_dir=tmp_path)
    return get, calls


def _rewrite(path, change, restamp: bool):
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(stamped(data) if restamp else data))


def _scale_theta(factor: float, only_b: bool = False):
    def change(data):
        m = data["talc_state"]["models"]["E_X0C"]
        na = m["orders"]["na"]
        m["theta"] = [v * factor if (not only_b or i >= na) else v for i, v in enumerate(m["theta"])]
    return change


@pytest.mark.parametrize("change, restamp, why", [
    (_scale_theta(1000.0), True, "ARX pole of radius"),
    (_scale_theta(1000.0, only_b=True), True, "on its training programme"),
    (_scale_theta(1.0001), False, "field 'sha256' does not match the content"),
    (lambda d: d.update(machine="swiss_lathe"), True, "identity is 'talc' of 'swiss_lathe', expected 'talc' of 'nmv5000'"),
])
def test_a_planted_cache_file_is_rebuilt_with_a_warning(cache, capsys, change, restamp, why):
    get, calls = cache
    path, built = get()
    assert built and get() == (path, False) and len(calls) == 1
    good = json.loads(path.read_text())["talc_state"]["models"]["E_X0C"]["theta"]
    _rewrite(path, change, restamp)
    capsys.readouterr()
    assert get() == (path, True) and len(calls) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("warning: prior cache: ") and why in err and err.endswith("rebuilding it")
    assert "\n" not in err
    rebuilt = load_prior(path)
    check_prior(rebuilt)
    assert rebuilt["talc_state"]["models"]["E_X0C"]["theta"] == good
