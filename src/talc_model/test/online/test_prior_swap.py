"""The model node's swap of a learned prior: checked when offered (hash, soft-sensor twin, the
run's configuration otherwise unchanged), warmed over the run's history a bounded number of
events per instant, handed over only when it has caught up and no probe is in flight (the
running model untouched until then), and exactly where a model started from that prior at the
run's first instant would be; every outcome is an audit line."""
import json

import pytest

from talc_model.online.audit import read_audit
from talc_model.online.history import RunHistory, feed
from talc_model.online.prior_swap import PriorSwap, adopted_config_path, config_change, prior_digest, resume_config
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.talc import load_prior

PROBE_EVERY = 24          # instants (2 h at 300 s)


def _instant(rec, k):
    return float(rec.time_s[k]), {"amb": float(rec.columns["amb_c"][k])}, {"C_axis_rpm": 0.0}


class Cell:
    """The node's order of work, without ROS: model the instant, record it, let the swap go on."""

    def __init__(self, priors, tmp_path, per_step=10, complete=True, state_path=None):
        self.rec = priors["plant"]
        self.model = model_from_prior("talc", priors["run_cfg"], load_prior(priors["type_prior"]))
        self.history = RunHistory(complete=complete)
        self.audit = tmp_path / "audit.jsonl"
        self.swap = PriorSwap("talc", priors["run_cfg"], str(priors["type_prior"]), self.history, per_step,
                              str(self.audit), state_path)
        self.k = 0
        self.swapped_at = None

    def step(self, busy=False):
        t, temps, state = _instant(self.rec, self.k)
        self.model.update_inputs(t, temps, state)
        pred, _ = self.model.predict(t)
        self.history.instant(t, temps, state)
        if self.k % PROBE_EVERY == 5:
            applied = {"E_X0C": pred["E_X0C"]}
            measured = {"E_X0C": float(self.rec.columns["E_X0C"][self.k]) - applied["E_X0C"]}
            self.model.add_measurement(t, measured, applied)
            self.history.probe(t, True, measured, applied)
        done = self.swap.step(t, busy)
        if done is not None:
            self.model, self.swapped_at = done.model, self.k
        self.k += 1
        return pred

    def offer(self, priors, prior=None, config=None):
        return self.swap.request(str(prior or priors["unit_prior"]), str(config or priors["unit_config"]),
                                 str(priors["report"]), ["E_X0C"], float(self.rec.time_s[self.k - 1]))


def test_a_learned_prior_is_warmed_in_bounded_steps_and_swapped_atomically(priors, tmp_path):
    cell = Cell(priors, tmp_path, per_step=10)
    for _ in range(120):
        cell.step()
    ok, msg, new = cell.offer(priors)
    assert ok and msg.startswith("accepted") and new == prior_digest(priors["unit_prior"])
    running = cell.model
    while cell.swapped_at is None:
        assert cell.model is running                     # untouched while the new one warms
        cell.step()
    # 120 instants and 5 probes at the offer, 10 events fed per instant, each adding one (and a
    # probe at instant 125): caught up at instant 133, in use from 134
    assert cell.swapped_at == 133
    # the swapped model is where a model started from the unit prior at the first instant is
    ref = model_from_prior("talc", priors["unit_cfg"], load_prior(priors["unit_prior"]))
    for ev in cell.history.events:
        feed(ref, ev)
    t, temps, state = _instant(cell.rec, cell.k)
    ref.update_inputs(t, temps, state)
    assert cell.step()["E_X0C"] == pytest.approx(ref.predict(t)[0]["E_X0C"], abs=1e-12)
    lines = read_audit(cell.audit)
    assert [ln["event"] for ln in lines] == ["swapped"]
    line = lines[0]
    assert line["old_prior_sha256"] == prior_digest(priors["type_prior"]) and line["new_prior_sha256"] == new
    assert line["decision"] == "adopt" and line["model_time_s"] == pytest.approx(133 * 300.0)
    assert line["figures"]["validation_rmse"] == {"E_X0C": {"type": 2.0, "unit": 0.4}}
    assert line["type_model"] == priors["unit_cfg"]["type_model"]
    assert cell.swap.current_sha256 == new and cell.swap.config["type_model"] == priors["unit_cfg"]["type_model"]


def test_no_swap_while_a_probe_is_in_flight(priors, tmp_path):
    cell = Cell(priors, tmp_path, per_step=1000)
    for _ in range(30):
        cell.step()
    assert cell.offer(priors)[0]
    cell.step(busy=True)
    assert cell.swapped_at is None and cell.swap.candidate is not None
    cell.step(busy=False)
    assert cell.swapped_at == 31


def _refused(cell, priors, match, **kw):
    ok, msg, _ = cell.offer(priors, **kw)
    assert not ok and "\n" not in msg
    assert match in msg, msg
    assert read_audit(cell.audit)[-1]["event"] == "adoption refused"
    assert read_audit(cell.audit)[-1]["reason"] == msg
    return msg


def test_offers_that_cannot_be_adopted_are_refused_in_one_line(priors, tmp_path):
    cell = Cell(priors, tmp_path)
    for _ in range(10):
        cell.step()
    # the prior's soft-sensor twin is not the configuration's: the integrity check
    _refused(cell, priors, "built on another twin's soft sensors", config=priors["run_config"])
    # the configuration changes more than the soft-sensor twin
    other = tmp_path / "other.yaml"
    other.write_text(json.dumps(dict(priors["unit_cfg"], post_cp_interval_h=1.0)))
    _refused(cell, priors, "key 'post_cp_interval_h' is 1.0, the run's is 2.0", config=other)
    # a prior file changed after it was written
    changed = tmp_path / "changed.json"
    changed.write_text(priors["unit_prior"].read_text().replace('"machine": "synthetic"', '"machine": "other"', 1))
    _refused(cell, priors, "does not match the content", prior=changed)
    # one swap at a time
    assert cell.offer(priors)[0]
    _refused(cell, priors, "is still warming")
    cell.step()
    assert cell.model is not None


def test_a_resumed_run_has_no_history_to_warm_from(priors, tmp_path):
    cell = Cell(priors, tmp_path, complete=False)
    cell.step()
    _refused(cell, priors, "the model resumed from a saved state")


def test_a_failing_warm_up_leaves_the_running_model(priors, tmp_path):
    cell = Cell(priors, tmp_path, per_step=5)
    for _ in range(20):
        cell.step()
    assert cell.offer(priors)[0]
    running = cell.model

    def broken(*a, **k):
        raise ValueError("input 'amb' is not finite")
    cell.swap.candidate.model.update_inputs = broken
    cell.step()
    assert cell.model is running and cell.swap.candidate is None
    assert read_audit(cell.audit)[-1]["reason"] == "warm-up failed at history event 0: input 'amb' is not finite"


def test_config_change_names_the_first_key_beyond_the_soft_sensor_twin():
    assert config_change({"a": 1, "type_model": "x"}, {"a": 1, "type_model": "y"}) == ""
    assert config_change({"a": 1}, {"a": 1, "b": 2}) == "key 'b' is 2, the run's is None"


def test_a_restarted_node_resumes_with_the_configuration_adopted_with_its_state(priors, tmp_path):
    state = tmp_path / "model.json"
    cell = Cell(priors, tmp_path, per_step=1000, state_path=state)
    for _ in range(10):
        cell.step()
    assert cell.offer(priors)[0]
    cell.step()
    assert cell.swapped_at == 10 and adopted_config_path(state).is_file()
    assert resume_config(state, priors["run_cfg"]) == priors["run_cfg"]        # no state saved: fresh start
    state.write_text("{}")
    assert resume_config(state, priors["run_cfg"]) == priors["unit_cfg"]
    assert resume_config(None, priors["run_cfg"]) == priors["run_cfg"]
