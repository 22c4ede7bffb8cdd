"""How the runs of a data set start, decided from the data: do they continue one another (one
recording cut into pieces) or is each a run of its own (a day's run after the machine stood)?

Every run's displacements start at 0 (its own start reference). What the temperatures and the
dynamic models' state must then be depends on how the run started:

- **continued**: a run's first temperatures are (within the noise of a step) the previous run's
  last ones. The runs laid end to end are the machine's history: absolute temperatures, and a
  dynamic model carries its state from one run into the next, as the machine did.
- **separate**: a run starts far from where the previous one ended (the machine stood between
  them, cooled down or warmed up with its hall). The state carried over from the previous run
  is then another day's state, and a map from absolute temperatures to displacements that start
  at 0 leaves a per-run offset f(T at the start) that no temperature explains. Each run is taken
  from its own start instead: its temperatures relative to its first reading (the reference of
  its displacements) and its first reading held ``rest_h`` hours before it, so the dynamic models
  start it in equilibrium (a machine that stood since the previous day is at rest).

The test (:func:`start_jumps`): per pair of consecutive runs in the data set's order, the jump of
each temperature from the end of one to the start of the next, over that sensor's range over the
two runs; the median over the sensors. A recording cut into segments jumps by well under 1 % of
the range, runs of different days by tens of per cent; :data:`CONTINUED_BELOW` separates them.
Pure.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from thermal_eval.datasets.runs import Run
from thermal_comp_common.recording_sources import DatasetError

#: a run continues the previous one when its temperatures' jump is below this share of their range
CONTINUED_BELOW = 0.10
#: hours at rest before each separate run (its first reading held): about three time constants
#: of a machine's fast parts, so a dynamic model starts the run near equilibrium
SEPARATE_REST_H = 3.0
MODES = ("auto", "continued", "separate")


@dataclass(frozen=True)
class RunStart:
    """How the runs are laid end to end: ``mode`` (continued / separate), the temperatures'
    reference (``temperatures_from_start``), the hours at rest before each run, and why."""

    mode: str
    temperatures_from_start: bool
    rest_h: float
    reason: str
    jumps: tuple[float, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return asdict(self) | {"jumps": [round(j, 4) for j in self.jumps], "said": self.describe()}

    def describe(self) -> str:
        how = ("absolute temperatures, dynamic state carried from run to run" if self.mode == "continued" else
               "each run's temperatures relative to its first reading"
               + (f", each run after {self.rest_h:g} h at rest" if self.rest_h else ""))
        return f"runs start: {self.mode} ({self.reason}): {how}"


def start_jumps(runs: Sequence[Run]) -> list[float]:
    """Per consecutive pair of runs: median over the sensors of |T_first(next) - T_last(previous)|
    over that sensor's range over both runs (a sensor that does not move counts 0)."""
    out = []
    for a, b in zip(runs[:-1], runs[1:]):
        ta, tb = a.data.temperatures, b.data.temperatures
        both = np.vstack([ta, tb])
        with np.errstate(all="ignore"):
            span = np.nanmax(both, axis=0) - np.nanmin(both, axis=0)
            last = np.array([_last_finite(ta[:, j]) for j in range(ta.shape[1])])
            first = np.array([_last_finite(tb[::-1, j]) for j in range(tb.shape[1])])
            ratio = np.where(span > 0, np.abs(first - last) / np.where(span > 0, span, 1.0), 0.0)
        ratio = ratio[np.isfinite(ratio)]
        out.append(float(np.median(ratio)) if ratio.size else 0.0)
    return out


def _last_finite(v: np.ndarray) -> float:
    ok = np.flatnonzero(np.isfinite(v))
    return float(v[ok[-1]]) if ok.size else float("nan")


def decide_run_start(runs: Sequence[Run], mode: str = "auto", rest_h: float | None = None) -> RunStart:
    """``auto``: separate when more than half of the consecutive pairs jump by at least
    :data:`CONTINUED_BELOW` of their temperatures' range, else continued; ``continued`` /
    ``separate`` force it. ``rest_h`` (None: :data:`SEPARATE_REST_H` for separate runs, 0 for
    continued ones) sets the hours at rest before each run."""
    if mode not in MODES:
        raise DatasetError(f"run start: {mode!r} must be one of {', '.join(MODES)}")
    if rest_h is not None and not (isinstance(rest_h, (int, float)) and 0 <= rest_h < 1e4):
        raise DatasetError(f"rest hours {rest_h!r}: must be a number in [0, 1e4)")
    jumps = start_jumps(runs)
    far = sum(j >= CONTINUED_BELOW for j in jumps)
    if mode != "auto":
        reason = "as asked"
    elif not jumps:
        mode, reason = "continued", "one run"
    else:
        mode = "separate" if far > len(jumps) / 2 else "continued"
        reason = (f"{far} of {len(jumps)} consecutive runs start >= {CONTINUED_BELOW:.0%} of their temperatures' "
                  f"range away from where the previous one ended (median jump {np.median(jumps):.1%})")
    separate = mode == "separate"
    rest = float(rest_h) if rest_h is not None else (SEPARATE_REST_H if separate else 0.0)
    return RunStart(mode, separate, rest, reason, tuple(jumps))
