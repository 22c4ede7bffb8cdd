"""What a finished ``thermal-comp learn`` decided, read from its ``report.json`` and trusted only
after checking: the adoption decision is learn's own held-out test (the unit twin better than the
type's open loop on validation probes the fit never saw, and the adaptive model from its prior
better than the one from the current prior by learn's margin, each probe predicted before it is
seen; docs/learn.md). A report that says adopt must name a prior and a model configuration that
exist. Everything refused is one line naming the field. No rclpy.
"""
from __future__ import annotations

import json
import math
import pathlib
from dataclasses import dataclass, field
from typing import Any


class ReportError(ValueError):
    """report.json is missing, not JSON, or a field is absent or of the wrong kind."""


@dataclass
class LearnDecision:
    adopt: bool
    reason: str
    prior_path: str = ""
    config_path: str = ""
    unit_twin: str = ""          # the learned twin the prior was built on
    figures: dict[str, Any] = field(default_factory=dict)


def _field(doc: dict, path: str, kind):
    cur: Any = doc
    for part in path.split("."):
        if not isinstance(cur, dict) or part not in cur:
            raise ReportError(f"report.json: field {path!r} is missing")
        cur = cur[part]
    if not isinstance(cur, kind):
        raise ReportError(f"report.json: field {path!r} is {type(cur).__name__}, expected {kind.__name__}")
    return cur


def _round(v):
    return round(v, 3) if isinstance(v, float) and math.isfinite(v) else v


def figures_of(doc: dict) -> dict[str, Any]:
    """The figures an audit line carries: the validation probes' RMSE type -> unit per component,
    how many probes decided, the prior learn's adaptive test was against, learn's wall time."""
    adoption = doc.get("adoption") or {}
    rmse = adoption.get("validation_rmse") or {}
    return {"validation_probes": adoption.get("validation_probes"),
            "validation_rmse": {c: {k: _round(v) for k, v in r.items()} for c, r in rmse.items()
                                if isinstance(r, dict)},
            "train_h": doc.get("train_h"), "recording_h": _round(doc.get("recording_h")),
            "tested_against": doc.get("tested_against"), "learn_wall_s": doc.get("wall_s")}


def read_decision(out: pathlib.Path) -> LearnDecision:
    """learn's decision from ``out/report.json`` (ReportError when it cannot be trusted)."""
    path = out / "report.json"
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise ReportError(f"{path}: learn wrote no report") from None
    except (OSError, ValueError) as exc:
        raise ReportError(f"{path}: not readable JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise ReportError(f"{path}: not a JSON object")
    adopt = _field(doc, "adoption.adopt", bool)
    reason = _field(doc, "adoption.reason", str)
    figures = figures_of(doc)
    if not adopt:
        return LearnDecision(False, reason, figures=figures)
    files = _field(doc, "files", dict)
    prior, config = files.get("prior"), files.get("model_config")
    for name, value in (("files.prior", prior), ("files.model_config", config)):
        if not isinstance(value, str) or not pathlib.Path(value).is_file():
            raise ReportError(f"report.json: adoption says adopt but field {name!r} is {value!r}, not a file")
    twin = files.get("unit_twin")
    return LearnDecision(True, reason, prior, config, twin if isinstance(twin, str) and pathlib.Path(twin).is_file()
                         else "", figures)
