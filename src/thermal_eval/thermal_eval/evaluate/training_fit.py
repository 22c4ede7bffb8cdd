"""What the closed-loop rows of models fitted on the training rows share, on any recording.

Such a model is given the training rows as its calibration phase: a real calibration phase
would have probed at every sample of TALC's 5-min grid of those rows, so those are its
calibration points and Q_prod over the whole recording charges them. Its hyper-parameters are
chosen by a walk-forward inside the training rows (fit on rows 0..k-1, replay k..n_train-1
under the same budget). After calibration it probes under the user's budget (a
:class:`thermal_eval.evaluate.adaptive.ProbingBudget`), as every adaptive row of ``evaluate``.
No rclpy here.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from thermal_eval.evaluate.spec import EvaluationData
from thermal_eval.evaluate.open_loop_models import GRID_STEP_S

#: Walk-forward fold starts as fractions of the training rows (fit before, replay after).
FOLD_STARTS = (0.6, 0.7, 0.8)


class TrainingFitError(ValueError):
    """Bad input to a row fitted on the training rows; the message names the argument and its value."""


def calibration_grid_rows(time_s: np.ndarray, n_calibration: int) -> np.ndarray:
    """Rows of the 5-min grid samples before ``n_calibration``: the charged calibration probings."""
    dt = float(np.median(np.diff(time_s)))
    step = max(1, int(round(GRID_STEP_S / dt)))
    return np.arange(0, n_calibration, step)


def walk_forward_fold_rows(fold_starts: Sequence[float], n: int) -> list[int]:
    """Row k of each walk-forward fold inside ``n`` training rows: fit on rows 0..k-1,
    replay k..n-1; each fold must leave >= 40 calibration and >= 20 replay rows."""
    rows = []
    for f in fold_starts:
        k = int(f * n)
        if k < 40 or n - k < 20:
            raise TrainingFitError(f"fold_starts: {f!r} of {n} training rows leaves calibration {k} / replay "
                                     f"{n - k} rows (need >= 40 / 20)")
        rows.append(k)
    return rows


def load_change_rows(data: EvaluationData) -> list[int]:
    """Rows where any machine input (speed, coolant, ...: known to the CNC) differs from the row
    before; none without inputs."""
    if data.inputs is None or data.inputs.size == 0:
        return []
    changed = np.any(np.diff(data.inputs, axis=0) != 0, axis=1)
    return [int(r) for r in np.flatnonzero(changed) + 1]


def refused_by_cap(probings_so_far: int, t_s: float, calibration_end_s: float, max_probes_per_h: float) -> bool:
    """The budget's hard cap (as :class:`thermal_eval.evaluate.model_rows.ProbingCap`): one more
    probing would exceed ``max_probes_per_h`` x the hours since the end of calibration."""
    return probings_so_far + 1 > max_probes_per_h * (t_s - calibration_end_s) / 3600.0
