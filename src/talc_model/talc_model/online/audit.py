"""The online learner's audit: one JSON line per decision, appended (never rewritten) with one
``write`` of an ``O_APPEND`` file, so the learner and the model node can share a file line by line.
A line: wall time (UTC), model time, event, decision, the prior in use before and after (SHA-256
of the prior file's content, its own ``sha256`` field), why, the figures behind it. No rclpy.
"""
from __future__ import annotations

import datetime
import json
import math
import os
import pathlib
from typing import Any, Mapping

from thermal_comp_common.json_figures import finite_figures

#: the events a line records
EVENTS = ("learn failed", "learn timed out", "not adopted", "adoption sent", "adoption refused", "swapped")


def audit_record(event: str, model_time_s: float, old_sha256: str, new_sha256: str, reason: str,
                 figures: Mapping[str, Any] | None = None, **extra: Any) -> dict[str, Any]:
    """One audit line's content."""
    if event not in EVENTS:
        raise ValueError(f"audit event {event!r} is none of {list(EVENTS)}")
    return {"wall_time_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "model_time_s": model_time_s if math.isfinite(model_time_s) else None,
            "event": event, "decision": "adopt" if event in ("adoption sent", "swapped") else "keep",
            "old_prior_sha256": old_sha256, "new_prior_sha256": new_sha256, "reason": reason,
            "figures": dict(figures or {}), **extra}


def append_audit(path: str | pathlib.Path | None, record: Mapping[str, Any]) -> str:
    """Append ``record`` as one line to ``path`` (None / "": nothing written); the line's text."""
    line = json.dumps(finite_figures(record), sort_keys=True, default=str, allow_nan=False)
    if path:
        p = pathlib.Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(p, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, (line + "\n").encode())
        finally:
            os.close(fd)
    return line



def read_audit(path: str | pathlib.Path) -> list[dict[str, Any]]:
    """Every line of an audit file (for the demo's table and the tests)."""
    p = pathlib.Path(path)
    if not p.is_file():
        return []
    return [json.loads(ln) for ln in p.read_text().splitlines() if ln.strip()]
