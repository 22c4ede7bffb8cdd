"""Joint re-estimation: alternate the estimate of a missing input and the finder's answer.

An input the recording lacks is estimated with the twin as given
(:func:`thermal_twin.calibrate.input_estimation.fill_missing_inputs`); when that twin itself lacks a
mechanism, the estimate is made with the wrong twin (the missing source's heat is put on the
sources the twin has, and the equivalent input is scaled by them). This module alternates the
two steps as a coordinate descent over (input, twin): estimate the input with the current
twin, diagnose the *given* twin against the recording completed with that estimate, take the
finder's augmented twin as the current twin, and repeat until the finder's first answer
repeats (a fixed point) or ``rounds`` are done. Whatever the finder answers is used: no word is
preferred. Every round is kept, so a report can show whether the answer moved.
Details and measured figures: docs/calibrate.md ("Inputs the recording lacks").
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from thermal_twin.calibrate.input_estimation import InputEstimate, fill_missing_inputs
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.diagnosis import Diagnosis, diagnose, shared_channels
from thermal_comp_common.recording_csv import Recording


@dataclass
class AlternationRound:
    first: str                       # the finder's first answer ("effect:target") or its answer word
    estimate: InputEstimate
    notes: list[str]
    diagnosis: Diagnosis
    recording: Recording             # the recording completed with this round's estimate


@dataclass
class Alternation:
    rounds: list[AlternationRound] = field(default_factory=list)
    converged: bool = False          # the first answer repeated

    @property
    def last(self) -> AlternationRound:
        return self.rounds[-1]


def first_answer(d: Diagnosis) -> str:
    """The finder's first adopted effect as ``effect:target``, else its answer word."""
    sel = d.report["selected"]
    return f"{sel[0]['effect']}:{sel[0]['target']}" if sel and sel != "none" else str(d.report["answer"])


def alternate(spec: dict, rec: Recording, responses: list[str] = (), rounds: int = 3,
              block_s: float = 1800.0, progress: Callable[[str], None] | None = None,
              fill: Callable = fill_missing_inputs, **diagnose_kw) -> Alternation:
    """Estimate the inputs ``rec`` lacks with the current twin (first ``spec``), diagnose
    ``spec`` against ``rec`` completed with them, continue with the finder's augmented twin;
    stop when the first answer repeats or after ``rounds`` (>= 1). ``fill`` makes the estimate
    (``fill(machine, rec, channels, block_s=, responses=)`` -> (recording, estimates, notes),
    as :func:`thermal_twin.calibrate.input_estimation.fill_missing_inputs`; e.g. an anchored one)."""
    if rounds < 1:
        raise ValueError(f"rounds: {rounds!r} must be at least 1")
    out = Alternation()
    current = spec
    for k in range(rounds):
        m = load_machine(current)
        filled, ests, notes = fill(m, rec, shared_channels(m, rec), block_s=block_s, responses=list(responses))
        if not ests:
            raise ValueError("alternate: the recording lacks no input the twin's sources need")
        d = diagnose(spec, filled, **diagnose_kw)
        first = first_answer(d)
        out.rounds.append(AlternationRound(first, ests[0], notes, d, filled))
        if progress:
            progress(f"alternation round {k + 1}: first answer {first}; {notes[0]}")
        if k > 0 and first == out.rounds[-2].first:
            out.converged = True
            break
        if d.augmented_spec is None:
            break
        current = d.augmented_spec
    return out
