"""talc_model.prior.history: a prior from a machine's own past runs (configuration from the columns,
identity with prior_source "history", a run started from it compensates from its first instant)."""
import math

import numpy as np
import pytest

from talc_model.adaptive_model import PHASE_COMPENSATION
from talc_model.prior.common import PriorError
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.history import HISTORY, build_history_prior, history_config
from talc_model.prior.talc import load_prior, save_prior
from thermal_comp_common.recording_csv import Recording


def _run(seed: int, hours: float = 24.0) -> Recording:
    """One day of a machine: two correlated temperatures and a third, an error lagging them."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 300.0)
    amb = 20 + sum(rng.uniform(0.5, 2) * np.sin(2 * np.pi * t / (rng.uniform(4, 30) * 3600) + rng.uniform(0, 6))
                   for _ in range(3))
    a = math.exp(-300.0 / (3 * 3600.0))
    e = np.zeros_like(t)
    for k in range(1, t.size):
        e[k] = a * e[k - 1] + (1 - a) * 3.0 * (amb[k - 1] - amb[0])
    return Recording(t, {"amb_c": amb, "amb2_c": amb + 0.01 * rng.normal(size=t.size), "ch1_um": e},
                     source=f"day {seed}")


def test_configuration_from_the_columns_and_refusals():
    runs = [_run(1), _run(2)]
    cfg = history_config("talc", runs)
    assert cfg["component_names"] == ["ch1"] and len(cfg["input_names"]) == 1     # one group of two sensors
    assert history_config("agp", runs)["sensors"] == ["amb", "amb2"]
    assert history_config("cd", runs, {"max_inputs": 1})["max_inputs"] == 1
    with pytest.raises(PriorError, match="need at least 2"):
        build_history_prior("talc", runs[:1])
    with pytest.raises(PriorError, match="model kind"):
        history_config("arx", runs)
    with pytest.raises(PriorError, match="no error column"):
        history_config("talc", [Recording(r.time_s, {"amb_c": r.columns["amb_c"]}) for r in runs])


@pytest.mark.parametrize("kind", ["talc", "agp"])
def test_history_prior_has_the_integrity_fields_and_a_run_starts_compensated(kind, tmp_path):
    runs = [_run(1), _run(2), _run(3)]
    prior = build_history_prior(kind, runs, machine="lathe-7")
    path = save_prior(tmp_path / "prior.json", prior)
    back = load_prior(path)                                     # hash and identity checked
    assert back["identity"]["prior_source"] == HISTORY and back["identity"]["model_kind"] == kind
    assert back["identity"]["machine"] == "lathe-7" and back["sources"] == ["day 1", "day 2", "day 3"]
    assert [r["hours"] for r in back["recordings"]] == [pytest.approx(24.0 - 300 / 3600, abs=1e-3)] * 3
    doc = path.read_text().replace('"prior_source": "history"', '"prior_source": "twin"', 1)
    (tmp_path / "forged.json").write_text(doc)
    with pytest.raises(PriorError):
        load_prior(tmp_path / "forged.json")
    model = model_from_prior(kind, back["run_config"], back)
    new = _run(9, hours=6.0)
    out = []
    for k in range(len(new)):
        t = float(new.time_s[k])
        model.update_inputs(t, {"amb": float(new.columns["amb_c"][k]), "amb2": float(new.columns["amb2_c"][k])}, {})
        out.append(model.predict(t)[0]["ch1"])
    e = new.columns["ch1_um"] - new.columns["ch1_um"][0]
    assert np.all(np.isfinite(out)) and np.ptp(out) > 0          # compensating before any probe
    if kind == "talc":                                           # the plant is TALC's model class
        assert model.phase == PHASE_COMPENSATION
        assert np.mean(np.abs(e - np.asarray(out))) < 0.2 * np.mean(np.abs(e))
