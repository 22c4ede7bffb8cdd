"""The online learner's core with a stand-in for ``thermal-comp learn`` (fake_learn.py): on the
schedule or on demand it snapshots the bag and runs learn in its own process; learn's adoption
decision alone makes an offer to the model node; a refusal, a failure, a hang (killed) and a
report that cannot be read are each one audit line, and the learner is free again."""
import json
import pathlib
import sys

import pytest

from talc_model.online.audit import read_audit
from talc_model.online.learner import LearnerConfig, OnlineLearner
from talc_model.online.prior_swap import prior_digest

FAKE = str(pathlib.Path(__file__).with_name("fake_learn.py"))
H = 3600.0


def _learner(tmp_path, mode, priors=None, timeout_s=60.0, every_h=24.0):
    bag = tmp_path / "bag"
    bag.mkdir(exist_ok=True)
    (bag / "bag_0.mcap").write_bytes(b"\x89MCAP0\r\n")        # the stand-in does not read it
    cmd = [sys.executable, FAKE, "--mode", mode]
    if priors is not None:
        cmd += ["--prior", str(priors["unit_prior"]), "--config", str(priors["unit_config"])]
    return OnlineLearner(LearnerConfig(recording=str(bag), twin="nmv5000", work_dir=str(tmp_path / "learn"),
                                       every_h=every_h, timeout_s=timeout_s, command=cmd,
                                       audit_path=str(tmp_path / "audit.jsonl"),
                                       prior_path=str(priors["type_prior"]) if priors else ""))


def _run_to_end(learner, now_s=10.0):
    learner.observe(0.0)
    learner.observe(24 * H)
    assert learner.poll(0.0) is None and learner.busy           # started, not waited for
    learner.job.proc.wait(timeout=60)
    return learner.poll(now_s)


def test_an_adopted_prior_is_offered_and_the_answer_audited(tmp_path, priors):
    learner = _learner(tmp_path, "adopt", priors)
    offer = _run_to_end(learner)
    assert offer.prior_path.endswith("learn_001_24.0h/out/prior.json")
    assert offer.sha256 == prior_digest(priors["unit_prior"]) and learner.busy
    assert (tmp_path / "learn" / "learn_001_24.0h" / "recording" / "bag_0.mcap").is_file()
    old = prior_digest(priors["type_prior"])
    learner.answered(True, "accepted: warming", old, offer.sha256)
    line = read_audit(tmp_path / "audit.jsonl")[-1]
    assert (line["event"], line["decision"], line["old_prior_sha256"], line["new_prior_sha256"]) == \
        ("adoption sent", "adopt", old, offer.sha256)
    assert line["figures"]["train_h"] == pytest.approx(0.8 * 24) and line["model_time_s"] == 24 * H
    assert learner.current_sha256 == offer.sha256 and not learner.busy
    # the next learning starts from, and is tested open loop against, the adopted unit's twin
    assert learner.twin == offer.unit_twin == str(tmp_path / "learn" / "learn_001_24.0h" / "out" / "unit_twin.yaml")
    # and its adaptive test is against the prior and configuration now running, not the type's
    learner.observe(48 * H)
    learner.poll(20.0)
    argv = learner.job.argv
    assert argv[argv.index("--twin") + 1] == offer.unit_twin
    assert (argv[argv.index("--current-prior") + 1], argv[argv.index("--current-config") + 1]) == \
        (offer.prior_path, offer.config_path)
    learner.job.proc.wait(timeout=60)
    report = json.loads((learner.job.work / "out" / "report.json").read_text())
    assert report["tested_against"] == {"prior": offer.prior_path, "model_config": offer.config_path}


def test_the_first_learning_is_tested_against_the_nodes_prior(tmp_path, priors):
    learner = _learner(tmp_path, "keep", priors)
    learner.observe(0.0)
    learner.observe(24 * H)
    learner.poll(0.0)
    argv = learner.job.argv
    assert argv[argv.index("--current-prior") + 1] == str(priors["type_prior"]) and "--current-config" not in argv
    learner.job.proc.wait(timeout=60)
    (tmp_path / "w").mkdir()
    without = _learner(tmp_path / "w", "keep")          # no prior_path: learn tests against the type's prior
    without.observe(0.0)
    without.request()
    without.poll(0.0)
    assert "--current-prior" not in without.job.argv
    without.job.proc.wait(timeout=60)


def test_learn_saying_no_keeps_the_model_and_is_audited(tmp_path, priors):
    learner = _learner(tmp_path, "keep", priors)
    assert _run_to_end(learner) is None and not learner.busy
    line = read_audit(tmp_path / "audit.jsonl")[-1]
    assert (line["event"], line["decision"], line["reason"]) == ("not adopted", "keep", "fake keep")
    assert line["old_prior_sha256"] == prior_digest(priors["type_prior"]) and line["new_prior_sha256"] == ""
    assert line["figures"]["validation_rmse"] == {"E_X0C": {"type": 2.0, "unit": 0.5}}
    assert line["figures"]["tested_against"] == {"prior": str(priors["type_prior"]), "model_config": ""}


@pytest.mark.parametrize("mode, event, reason", [
    ("fail", "learn failed", "learn exited with code 2: thermal-comp learn: a recording without probing results"),
    ("bad-report", "learn failed", "not readable JSON")])
def test_a_failed_learn_is_reported_and_the_learner_is_free(tmp_path, mode, event, reason):
    learner = _learner(tmp_path, mode)
    assert _run_to_end(learner) is None and not learner.busy
    line = read_audit(tmp_path / "audit.jsonl")[-1]
    assert line["event"] == event and reason in line["reason"]


def test_a_hanging_learn_is_killed_after_its_timeout(tmp_path):
    learner = _learner(tmp_path, "hang", timeout_s=5.0)
    learner.observe(0.0)
    learner.request()
    assert learner.poll(100.0) is None and learner.busy
    proc = learner.job.proc
    assert learner.poll(104.0) is None and proc.poll() is None      # within its time
    assert learner.poll(106.0) is None and not learner.busy
    assert proc.returncode is not None
    assert read_audit(tmp_path / "audit.jsonl")[-1]["event"] == "learn timed out"


def test_requests_on_demand(tmp_path):
    learner = _learner(tmp_path, "hang", timeout_s=5.0, every_h=0.0)
    assert learner.request() == (False, "no model instant seen yet: nothing recorded to learn from")
    learner.observe(0.0)
    assert learner.request()[0]
    learner.poll(0.0)
    ok, msg = learner.request()
    assert not ok and msg.startswith("busy: learning 1 (on demand)")
    learner.stop()
    assert read_audit(tmp_path / "audit.jsonl")[-1]["reason"] == "the learner stopped while learn ran: killed"


def test_a_restarted_learner_never_reuses_a_folder(tmp_path):
    (tmp_path / "learn" / "learn_001_0.0h").mkdir(parents=True)
    learner = _learner(tmp_path, "keep", every_h=0.0)
    learner.observe(0.0)
    learner.request()
    learner.poll(0.0)
    assert learner.job.work.name == "learn_002_0.0h"
    learner.job.proc.wait(timeout=60)


def test_a_bad_configuration_is_refused():
    with pytest.raises(ValueError, match="train_fraction"):
        LearnerConfig(recording="b", twin="t", work_dir="w", train_fraction=1.0, command=["x"])
