"""What is loaded is checked before use: a prior file or model state changed after it was
written (hash), relabelled (identity), of another twin or other inputs than the run, or with
ARX models that diverge or err beyond the bound on the prior's own training programme is
refused in one line naming the field."""
import copy
import json
import logging

import numpy as np
import pytest

from talc_model.model_persistence import (HASH_FIELD, ModelStateError, content_hash, load_model, read_state,
                                          save_model)
from talc_model.prior.common import PriorError
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.integrity import check_prior, stamped
from talc_model.prior.talc import build_talc_prior, load_prior, save_prior, talc_with_prior
from talc_model.state_files import run_identity
from talc_model.talc.model import TalcModel
from test_prior_model import CFG, _plant


@pytest.fixture(scope="module")
def prior():
    return build_talc_prior([_plant(1), _plant(2), _plant(3)], CFG, machine="synthetic", nb_max=2,
                            sources=["p1", "p2", "p3"])


def _one_line(exc_info) -> str:
    text = str(exc_info.value)
    assert "\n" not in text
    return text


def _scaled(prior, factor: float, only_b: bool = False) -> dict:
    out = copy.deepcopy(prior)
    for m in out["talc_state"]["models"].values():
        na = m["orders"]["na"]
        m["theta"] = [v * factor if (not only_b or i >= na) else v for i, v in enumerate(m["theta"])]
    return out


def test_a_valid_prior_round_trips_with_its_identity_and_hash(prior, tmp_path):
    path = save_prior(tmp_path / "p.json", prior)
    data = json.loads(path.read_text())
    assert data["identity"] == {"format_version": 2, "machine": "synthetic", "model_kind": "talc",
                                "type_model": "", "input_names": ["amb"]}
    assert data[HASH_FIELD] == content_hash(data, HASH_FIELD)
    assert data["training_check"]["programme"] == "p3"
    check_prior(load_prior(path))
    assert talc_with_prior(CFG, load_prior(path)).models


def test_x1000_scaled_arx_prior_is_refused_even_with_a_fresh_hash(prior, tmp_path):
    scaled = load_prior(save_prior(tmp_path / "x1000.json", _scaled(prior, 1000.0)))   # re-stamped: hash passes
    with pytest.raises(PriorError, match=r"component 'E_X0C': ARX pole of radius .* not inside the unit circle") as e:
        model_from_prior("talc", CFG, scaled)
    _one_line(e)
    gain = load_prior(save_prior(tmp_path / "b1000.json", _scaled(prior, 1000.0, only_b=True)))
    with pytest.raises(PriorError, match=r"'E_X0C' errs P99 .* on its training programme 'p3', above the bound") as e:
        talc_with_prior(CFG, gain)
    _one_line(e)


def test_a_flipped_byte_is_refused_by_the_hash(prior, tmp_path):
    path = save_prior(tmp_path / "p.json", prior)
    text = path.read_text()
    i = text.index('"theta": [') + len('"theta": [') + 3            # a digit of the first parameter
    flipped = "1" if text[i] != "1" else "2"
    path.write_text(text[:i] + flipped + text[i + 1:])
    with pytest.raises(PriorError, match=rf"prior '{path}': field 'sha256' does not match the content") as e:
        load_prior(path)
    _one_line(e)


def test_a_relabelled_prior_is_refused(prior, tmp_path):
    path = save_prior(tmp_path / "p.json", prior)
    data = json.loads(path.read_text())
    data["machine"] = "swiss_lathe"
    path.write_text(json.dumps(data))
    with pytest.raises(PriorError, match="field 'sha256' does not match") as e:
        load_prior(path)
    _one_line(e)
    data[HASH_FIELD] = content_hash(data, HASH_FIELD)                # relabelled and re-hashed
    path.write_text(json.dumps(data))
    with pytest.raises(PriorError, match="identity 'machine' is 'synthetic', its content says 'swiss_lathe'") as e:
        load_prior(path)
    _one_line(e)


def test_a_prior_without_hash_is_refused(prior, tmp_path):
    old = {k: v for k, v in stamped(prior).items() if k not in ("identity", HASH_FIELD)}
    (tmp_path / "v1.json").write_text(json.dumps({**old, "version": 1}))
    with pytest.raises(PriorError, match="'version' 1 is not 2 .* rebuild it with thermal-comp prior") as e:
        load_prior(tmp_path / "v1.json")
    _one_line(e)
    (tmp_path / "nohash.json").write_text(json.dumps(old))
    with pytest.raises(PriorError, match="no 'sha256' field") as e:
        load_prior(tmp_path / "nohash.json")
    _one_line(e)


def test_a_prior_of_another_twin_or_other_inputs_than_the_run_is_refused(prior):
    other_twin = copy.deepcopy(prior)
    other_twin["talc_state"]["config"]["type_model"] = "other_twin.yaml"
    with pytest.raises(PriorError, match="'type_model' is 'other_twin.yaml', the run's is 'nmv5000'") as e:
        model_from_prior("talc", {**CFG, "type_model": "nmv5000"}, other_twin)
    _one_line(e)
    with pytest.raises(PriorError, match=r"'input_names' are \['amb'\], the run's are \['ambient'\]") as e:
        model_from_prior("talc", {**CFG, "input_names": ["ambient"]}, prior)
    _one_line(e)


def _trained(cfg) -> TalcModel:
    model = TalcModel(cfg)
    rec = _plant(5, hours=6.0)
    for k, t in enumerate(rec.time_s):
        model.update_inputs(float(t), {"amb": float(rec.columns["amb_c"][k])}, {})
    return model


def test_a_state_of_other_inputs_is_refused_on_resume(tmp_path):
    path = tmp_path / "state.json"
    save_model(path, _trained(CFG))
    assert read_state(path)["identity"]["input_names"] == ["amb"]
    same = run_identity(CFG, TalcModel(CFG))
    assert load_model(path, "talc", expected=same).input_names == ["amb"]
    other = {**CFG, "input_names": ["ambient", "cutting_oil"]}
    with pytest.raises(ModelStateError, match=r"identity 'input_names' is \['amb'\], the run's is "
                                              r"\['ambient', 'cutting_oil'\]") as e:
        load_model(path, "talc", expected=run_identity(other, TalcModel(other)))
    _one_line(e)


def test_a_changed_state_is_refused_and_an_old_one_loads_with_a_warning(tmp_path, caplog):
    path = tmp_path / "state.json"
    save_model(path, _trained(CFG))
    doc = json.loads(path.read_text())
    doc["state"]["input_names"] = ["ambient"]
    path.write_text(json.dumps(doc))
    with pytest.raises(ModelStateError, match=rf"{path}: key 'sha256' does not match the content") as e:
        load_model(path)
    _one_line(e)
    doc["state"]["input_names"] = ["amb"]
    old = {k: v for k, v in doc.items() if k not in ("identity", HASH_FIELD)}
    path.write_text(json.dumps({**old, "version": 1}))
    with caplog.at_level(logging.WARNING, logger="talc_model"):
        assert load_model(path).input_names == ["amb"]
    assert "integrity was not checked" in caplog.text


def test_the_training_check_is_deterministic_and_holds_for_the_built_prior(prior):
    check = prior["training_check"]
    assert np.asarray(check["u"]).shape[0] == len(check["errors"]["E_X0C"]) > 100
    assert check["uncompensated_p99"]["E_X0C"] > 1.0
    check_prior(prior)


@pytest.mark.ros
def test_the_node_refuses_to_resume_a_state_of_other_inputs(tmp_path, ros_domain_id):
    import rclpy                                         # ROS only in this test (marked ros)
    from talc_model.talc_model_node import TalcModelNode  # the node needs rclpy

    state = tmp_path / "model.json"
    save_model(state, _trained(CFG))                     # inputs ['amb']
    cfg = tmp_path / "talc.yaml"
    cfg.write_text(json.dumps({**CFG, "input_names": ["ambient", "cutting_oil"]}))    # JSON is YAML
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=["--ros-args", "-p", f"model_config:={cfg}", "-p", f"state_path:={state}",
                                  "-p", "action_server_wait_s:=0.0"])
    try:
        with pytest.raises(ModelStateError, match=rf"{state}: identity 'input_names' is \['amb'\]") as e:
            TalcModelNode(context=ctx)
        _one_line(e)
    finally:
        ctx.try_shutdown()
