"""What the priors of TALC, the AGP and characteristic diagrams share: the prior file version,
the error type, the training errors as deltas and the restore of a prior-started model.
No rclpy here. docs/prior.md.
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

#: version of the prior files ("kind": "prior") of every model kind; 2 carries the identity
#: block and the content hash (talc_model.prior.integrity)
PRIOR_VERSION = 2


class PriorError(ValueError):
    """A prior cannot be built or used; the message names the field and value."""


def error_deltas(recording, component: str) -> np.ndarray:
    """The error of ``component`` in a training recording as deltas from its first finite
    value (the run's errors are deltas from its start); shared by the AGP and CD priors."""
    col = component if component in recording.columns else f"{component}_um"
    if col not in recording.columns:
        raise PriorError(f"prior: component {component!r} has no error column in the training recording")
    e = np.asarray(recording.columns[col], float)
    ok = np.isfinite(e)
    return e - (e[ok][0] if ok.any() else 0.0)      # the run's errors are deltas from its start too


def restore_with_prior(model, base_cls, state: Mapping[str, Any]):
    """``model`` (a prior-started model just built from ``state``'s settings) given the learnt state
    of ``base_cls.from_state`` (everything but the prior) and the prior's input origin ``x0``."""
    base = base_cls.from_state({k: v for k, v in state.items() if k != "prior"})
    for key, value in vars(base).items():
        if key != "config":
            setattr(model, key, value)
    model.x0 = None if state["x0"] is None else np.asarray(state["x0"], dtype=float)
    return model
