"""Atomic persistence: round trip, resume without recalibration, pre-trained start."""
import json
import os

import pytest

from talc_model.model_persistence import (HASH_FIELD, ModelStateError, content_hash, load_model, load_pretrained,
                                          model_identity, read_state, save_model)
from talc_model.talc.model import TalcModel
from test_talc import COMPONENTS, STEP, config, plant, run


def _trained(n=120):
    u, errors = plant(n + 100)
    m = run(TalcModel(config(update_interval_h=3.0)), u, errors, 0, n)
    assert m.phase == "compensation"
    return m, u, errors


def test_round_trip_resumes_identically_without_recalibration(tmp_path):
    m, u, errors = _trained()
    path = tmp_path / "state" / "talc.json"
    save_model(path, m, extra={"note": "test"})
    assert [p.name for p in path.parent.iterdir()] == ["talc.json"]     # no temp file left
    restored = load_model(path, expected_kind="talc")
    assert restored.phase == "compensation"
    assert restored.to_state() == json.loads(json.dumps(m.to_state()))
    # both go on with the same inputs: identical predictions, probes and updates, no new CP
    log_a, log_b = [], []
    run(m, u, errors, 120, 220, log=log_a)
    run(restored, u, errors, 120, 220, log=log_b)
    assert [k for k, *_ in log_a] == [k for k, *_ in log_b]
    assert all(ph != "calibration" for _, ph, _ in log_b)
    for c in COMPONENTS:
        assert m.predict(220 * STEP)[0][c] == restored.predict(220 * STEP)[0][c]
    assert restored.status(220 * STEP).parameter_updates == m.status(220 * STEP).parameter_updates
    assert read_state(path)["extra"] == {"note": "test"}


def test_save_replaces_atomically_and_keeps_old_state_on_failure(tmp_path, monkeypatch):
    m, *_ = _trained(60)
    path = tmp_path / "talc.json"
    save_model(path, m)
    before = path.read_text()

    def boom(*a, **k):
        raise OSError("disk full")
    monkeypatch.setattr(os, "replace", boom)
    m.add_failed_measurement(60 * STEP, "test")
    with pytest.raises(OSError, match="disk full"):
        save_model(path, m)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["talc.json"]


def test_bad_files_are_reported_with_their_path(tmp_path):
    with pytest.raises(ModelStateError, match="no such"):
        load_model(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ModelStateError, match="bad.json"):
        load_model(bad)
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"format": "other"}))
    with pytest.raises(ModelStateError, match="'format'"):
        load_model(wrong)
    m, *_ = _trained(60)
    save_model(tmp_path / "ok.json", m)
    with pytest.raises(ModelStateError, match="'kind'"):
        load_model(tmp_path / "ok.json", expected_kind="agp")
    doc = json.loads((tmp_path / "ok.json").read_text())
    del doc["state"]["grid"]
    doc[HASH_FIELD] = content_hash(doc, HASH_FIELD)      # malformed but consistently hashed
    (tmp_path / "broken.json").write_text(json.dumps(doc))
    with pytest.raises(ModelStateError, match="grid"):
        load_model(tmp_path / "broken.json")


def test_pretrained_model_starts_compensating_at_once(tmp_path):
    m, u, errors = _trained()
    save_model(tmp_path / "trained.json", m)
    fresh = load_pretrained(tmp_path / "trained.json", {"post_cp_interval_h": 2.0})
    assert fresh.phase == "compensation" and fresh.probing_cycles == 0
    assert fresh.config.post_cp_interval_h == 2.0
    # the same plant from rest: predictions from the first step on, no calibration phase
    log = []
    run(fresh, u, errors, 0, 40, t_offset=1e6, log=log)
    assert all(ph != "calibration" for _, ph, _ in log)
    assert fresh.parameter_updates == 0 or all(e["event"] != "calibration_end" for e in fresh.events)
    residuals = [abs(meas["E_X0C"]) for _, _, meas in log]
    assert max(residuals) < 1e-6            # the trained parameters are exact for this plant
    with pytest.raises(ModelStateError, match="no fitted parameters"):
        cp = TalcModel(config())
        cp.update_inputs(0.0, {"a": 1.0, "b": 1.0}, {})
        save_model(tmp_path / "cp.json", cp)
        load_pretrained(tmp_path / "cp.json")


def test_pretrained_model_of_other_inputs_or_twin_is_refused(tmp_path):
    m, _, _ = _trained()
    m.config.type_model = "nmv5000"          # as if trained on that twin's soft sensors
    save_model(tmp_path / "trained.json", m)
    ident = model_identity(m)
    assert ident["input_names"] and ident["type_model"] == "nmv5000"
    load_pretrained(tmp_path / "trained.json",           # the run's own identity passes
                    expected={"input_names": [ident["input_names"]], "type_model": ["nmv5000"]})
    with pytest.raises(ModelStateError, match="identity 'input_names'"):
        load_pretrained(tmp_path / "trained.json", expected={"input_names": [["T_other", "T_hall"]]})
    with pytest.raises(ModelStateError, match="identity 'type_model'"):
        load_pretrained(tmp_path / "trained.json", expected={"type_model": ["lathe_twin"]})
