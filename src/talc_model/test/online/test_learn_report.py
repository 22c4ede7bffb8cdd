"""learn's report is trusted only after checking: an adoption must name a prior and a model
configuration that exist; a missing or mistyped field is one line naming it. Audit lines are
appended as JSON, a figure that does not exist written as null."""
import json
import math

import pytest

from talc_model.online.audit import append_audit, audit_record, read_audit
from talc_model.online.learn_report import ReportError, read_decision


def _report(tmp_path, **adoption):
    (tmp_path / "report.json").write_text(json.dumps({"adoption": {"adopt": True, "reason": "r", **adoption},
                                                      "files": {"prior": str(tmp_path / "prior.json")}}))


def test_an_adoption_must_name_existing_files(tmp_path):
    _report(tmp_path)
    with pytest.raises(ReportError, match=r"field 'files.prior' is '.*prior.json', not a file"):
        read_decision(tmp_path)
    (tmp_path / "prior.json").write_text("{}")
    with pytest.raises(ReportError, match=r"field 'files.model_config' is None, not a file"):
        read_decision(tmp_path)


def test_missing_or_mistyped_fields(tmp_path):
    with pytest.raises(ReportError, match="learn wrote no report"):
        read_decision(tmp_path)
    _report(tmp_path, adopt="yes")
    with pytest.raises(ReportError, match=r"field 'adoption.adopt' is str, expected bool"):
        read_decision(tmp_path)
    (tmp_path / "report.json").write_text(json.dumps({"files": {}}))
    with pytest.raises(ReportError, match=r"field 'adoption.adopt' is missing"):
        read_decision(tmp_path)


def test_audit_lines_append_and_carry_no_nan(tmp_path):
    path = tmp_path / "a" / "audit.jsonl"
    append_audit(path, audit_record("not adopted", 3600.0, "old", "", "worse", {"rmse": math.nan}))
    append_audit(path, audit_record("swapped", math.inf, "old", "new", "ok"))
    lines = read_audit(path)
    assert [(ln["event"], ln["decision"]) for ln in lines] == [("not adopted", "keep"), ("swapped", "adopt")]
    assert lines[0]["figures"] == {"rmse": None} and lines[1]["model_time_s"] is None
    with pytest.raises(ValueError, match="audit event 'x'"):
        audit_record("x", 0.0, "", "", "")
    assert append_audit("", audit_record("swapped", 0.0, "", "", "")).startswith("{")
