"""Text pieces every learn report.md shares: a figure, and the line naming the prior the adaptive
test was against. No rclpy."""
from __future__ import annotations

import math
from typing import Any, Mapping


def fmt(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3g}"


def tested_against_lines(ref: Mapping[str, Any] | None) -> list[str]:
    """The line naming the prior the adaptive test was against (none without priors)."""
    if not ref:
        return []
    who = ("the prior built on the twin given (--twin: a preset or a twin file)" if ref["source"] == "type"
           else "the prior running now (--current-prior)")
    cfg = f", configuration `{ref['model_config']}`" if ref.get("model_config") else ""
    return [f"Tested against {who}: `{ref['prior']}` (sha256 {ref['sha256']}{cfg}; soft-sensor twin "
            f"`{ref['type_model'] or '-'}`).", ""]
