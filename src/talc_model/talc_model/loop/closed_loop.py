"""The model's own loop (temperatures -> model -> compensation -> probe), shared by the node and offline runs.

:class:`ClosedLoop` drives an :class:`~talc_model.adaptive_model.AdaptiveModel` instant by
instant: update, predict, hand the compensation to a :class:`CompensationSink` (the node's
bridge topic, the virtual experiment's plant, the fault injection's safety envelope), start
a probing cycle when the model says so (:class:`~talc_model.probing.cycle_state.ProbingStateMachine`)
and feed the result back: the probe sees the residual, the model is told what was applied,
so total error = residual + applied. A probe is a callable (offline) or an asynchronous
result the shell reports (the node's ProbeCycle action). Q_prod is the model's own count.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping, Protocol

from talc_model.adaptive_model import AdaptiveModel
from talc_model.probing.cycle_state import Action, ProbeOutcome, ProbeState, ProbingError, ProbingStateMachine


class CompensationSink(Protocol):
    """Where the prediction goes, and what compensation a probe at t would see."""

    def apply(self, t_s: float, values: Mapping[str, float], stds: Mapping[str, float]) -> None: ...

    def applied(self, t_s: float) -> dict[str, float]: ...


class HeldCompensation:
    """The prediction applied in full (NaN -> 0) and held until the next one."""

    def __init__(self, components):
        self.components = list(components)
        self.values = {c: 0.0 for c in self.components}

    def apply(self, t_s: float, values: Mapping[str, float], stds: Mapping[str, float] | None = None) -> None:
        self.values = {c: _finite_or_zero(values.get(c, math.nan)) for c in self.components}

    def applied(self, t_s: float) -> dict[str, float]:
        return dict(self.values)


class ProbeFailed(Exception):
    """Raised by a synchronous probe: the cycle failed (never learned from); str = the reason."""


#: A synchronous probe: (t_s, applied compensation) -> measured residual per component.
Probe = Callable[[float, Mapping[str, float]], Mapping[str, float]]


class StepKind(enum.Enum):
    NEW = "new"              # the model learned from the instant and predicted
    REPEAT = "repeat"        # (live) the same instant again: the same prediction, no second update
    LATE = "late"            # (live) older than the last instant: ignored
    REJECTED = "rejected"    # (live) the model refused the inputs (``error`` says why)


@dataclass
class Step:
    t_s: float
    kind: StepKind
    values: dict[str, float] = field(default_factory=dict)     # the compensation applied
    stds: dict[str, float] = field(default_factory=dict)
    action: Action = Action.NONE                                # what the shell must do for the probe
    outcome: ProbeOutcome | None = None                         # a synchronous probe's outcome
    error: str = ""


class ResumedStateMismatch(ValueError):
    """A resumed model state whose time does not fit the first instant of the graph."""

    def __init__(self, state_path, saved_time_s: float, graph_time_s: float):
        self.state_path, self.saved_time_s, self.graph_time_s = state_path, saved_time_s, graph_time_s
        super().__init__(f"model state {state_path} was saved at model time {saved_time_s:.3f} s, after the "
                         f"graph's first instant {graph_time_s:.3f} s (a state from another run): refused")


@dataclass(frozen=True)
class ResumedState:
    """Where a resumed model came from and the model time it was saved at."""

    path: str
    time_s: float


class ClosedLoop:
    """One closed loop (see the module docstring).

    ``apply_after_probe``: the probe at t sees the compensation in effect before t's
    prediction, and the prediction applied at t is made after learning from the probe;
    default: t's prediction is applied first and the probe sees it. ``live``: a stream
    from a running graph (late instants ignored, a re-sent instant answered again, bad
    input reported in the step instead of raised). ``resumed``: the first instant must
    not be before the state's saved time, else :class:`ResumedStateMismatch`.
    """

    def __init__(self, model: AdaptiveModel, sink: CompensationSink, *, probe: Probe | None = None,
                 probing: ProbingStateMachine | None = None, apply_after_probe: bool = False,
                 live: bool = False, resumed: ResumedState | None = None):
        self.model = model
        self.sink = sink
        self.probe = probe
        self.probing = probing or ProbingStateMachine()
        self.apply_after_probe = apply_after_probe
        self.live = live
        self.resumed = resumed
        self.t_last = -math.inf
        self.last: Step | None = None
        self.probe_times_s: list[float] = []

    def replace_model(self, model: AdaptiveModel) -> None:
        """Start over with ``model`` (e.g. a fresh one after a refused resumed state)."""
        self.model = model
        self.resumed = None

    # ------------------------------------------------------------------ one instant
    def step(self, t_s: float, temperatures: Mapping[str, float], machine_state: Mapping[str, float],
             now_s: float = 0.0, wait_for_offsets: bool = False) -> Step:
        """Process instant ``t_s``; with a synchronous probe the whole cycle runs here."""
        self._check_resumed(t_s)
        if self.live and t_s < self.t_last:
            return Step(t_s, StepKind.LATE)
        if self.live and t_s == self.t_last and self.last is not None:
            return Step(t_s, StepKind.REPEAT, self.last.values, self.last.stds)
        self.t_last = t_s
        try:
            self.model.update_inputs(t_s, temperatures, machine_state)
            values, stds = self.model.predict(t_s)
        except ValueError as exc:
            if not self.live:
                raise
            return Step(t_s, StepKind.REJECTED, error=str(exc))
        step = Step(t_s, StepKind.NEW, values, stds)
        if not self.apply_after_probe:
            self.sink.apply(t_s, values, stds)
        if not self.probing.busy and self.model.probe_due(t_s):
            self.probe_times_s.append(t_s)
            step.action = self.probing.request(t_s, now_s, wait_for_offsets)
            if self.probe is not None:
                step.outcome = self._probe_now(t_s)
                step.action = Action.NONE
                if self.apply_after_probe:
                    step.values, step.stds = self.model.predict(t_s)
        if self.apply_after_probe:
            self.sink.apply(t_s, step.values, step.stds)
        self.last = step
        return step

    def _probe_now(self, t_s: float) -> ProbeOutcome:
        if self.probing.state is not ProbeState.WAIT_ACCEPT:
            raise ProbingError(f"a synchronous probe at {t_s:.0f} s cannot wait for offsets "
                               f"(cycle {self.probing.state.value})")
        applied = self.goal_sent()
        self.probing.accepted(t_s)
        try:
            measured = self.probe(t_s, applied)
        except ProbeFailed as exc:
            return self.probe_failed(t_s, str(exc))
        return self.probe_result(t_s, measured)

    def _check_resumed(self, t_s: float) -> None:
        if self.resumed is None:
            return
        if self.resumed.time_s > t_s:
            raise ResumedStateMismatch(self.resumed.path, self.resumed.time_s, t_s)
        self.resumed = None

    # ------------------------------------------------------------------ probing events
    def goal_sent(self) -> dict[str, float]:
        """The shell starts the cycle now: the compensation the probe will see (recorded)."""
        applied = self.sink.applied(self.probing.t_s)
        self.probing.goal_sent(applied)
        return applied

    def offsets_arrived(self, stamp_s: float, now_s: float) -> Action:
        return self.probing.offsets_arrived(stamp_s, now_s)

    def accepted(self, t_s: float) -> bool:
        return self.probing.accepted(t_s)

    def probe_result(self, t_s: float, measured: Mapping[str, float]) -> ProbeOutcome | None:
        """The residual measured by the cycle at ``t_s``: learned from (None: stale, ignored).
        Live, a result the model refuses becomes a failed cycle."""
        outcome = self.probing.succeeded(t_s, measured)
        if outcome is None:
            return None
        applied = {c: outcome.applied.get(c, 0.0) for c in outcome.measured}
        try:
            self.model.add_measurement(t_s, outcome.measured, applied)
        except ValueError as exc:
            if not self.live:
                raise
            reason = f"result not usable: {exc}"
            self.probing.failed += 1
            self.model.add_failed_measurement(t_s, reason)
            return ProbeOutcome(t_s, False, {}, outcome.applied, reason)
        return outcome

    def probe_failed(self, t_s: float | None, reason: str) -> ProbeOutcome | None:
        """The cycle at ``t_s`` (None: the current one) failed: counted, never learned from."""
        outcome = self.probing.failed_cycle(t_s, reason)
        if outcome is not None:
            self.model.add_failed_measurement(outcome.t_s, reason)
        return outcome

    def tick(self, now_s: float) -> tuple[Action, ProbeOutcome | None]:
        """Deadlines: SEND_GOAL (offsets late) or CANCEL_GOAL with the failed outcome (result late)."""
        action, outcome = self.probing.tick(now_s)
        if outcome is not None:
            self.model.add_failed_measurement(outcome.t_s, outcome.reason)
        return action, outcome


def _finite_or_zero(v: float) -> float:
    return v if math.isfinite(v) else 0.0
