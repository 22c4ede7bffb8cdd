"""Figures as standard JSON: a figure that does not exist (NaN, +-inf) is written as null, so
files stay readable by every JSON parser and ``json.dumps(..., allow_nan=False)`` holds. No rclpy."""
from __future__ import annotations

import math
from typing import Any, Mapping


def finite_figures(value: Any) -> Any:
    """``value`` with every non-finite float (numpy's included) in mappings, lists and tuples -> None."""
    if isinstance(value, float):          # numpy.float64 is a float
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {k: finite_figures(x) for k, x in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_figures(x) for x in value]
    return value
