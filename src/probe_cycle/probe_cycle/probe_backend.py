"""The one interface every probing backend offers: execute one probing move, report the skip.

A backend turns a :class:`~probe_cycle.cycle_plan.TouchMove` into a :class:`TouchReply`
(triggered, axis position at the skip in mm, trigger instant on the machine's clock), or
raises :class:`ProbeBackendError` saying why. :class:`ArtefactModelBackend` (here) is the
in-process forward model; the others are listed in README.md ("Layout").
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from thermal_twin.machine.artefact_geometry import ArtefactGeometry, touch_trigger_position

from probe_cycle.cycle_plan import TouchMove


class ProbeBackendError(RuntimeError):
    """The backend could not execute a probing move."""


@dataclass(frozen=True)
class TouchReply:
    triggered: bool
    position_mm: np.ndarray        # (3,) skip position, or the end of an untriggered move
    stamp_s: float                 # instant of the trigger on the machine's clock, s
    message: str = ""


class ProbeBackend(abc.ABC):
    """Executes probing moves on a machine (real or simulated)."""

    name: str = "backend"

    @abc.abstractmethod
    def touch(self, move: TouchMove) -> TouchReply:
        """Execute one probing move; raise :class:`ProbeBackendError` if impossible."""

    def stop(self) -> None:
        """Called from another thread when the node stops: end a move in progress as soon as
        the backend can (its ``touch`` raises :class:`ProbeBackendError`) and refuse new ones.
        Default: nothing in progress can block (in-process backends)."""

    def close(self) -> None:  # pragma: no cover - default: nothing to release
        """Release connections."""


@dataclass
class ArtefactModelBackend(ProbeBackend):
    """Probing on the physical forward model with given true errors and offsets.

    ``errors`` and ``offsets`` can be callables of the current time (s), so a test can
    drift the errors during a cycle. Each move advances the model clock by its duration,
    and the trigger is taken at the end of the move.
    """

    errors: Mapping[str, float] | Callable[[float], Mapping[str, float]] = field(
        default_factory=dict)
    offsets_um: Mapping[str, float] | Callable[[float], Mapping[str, float]] = field(
        default_factory=dict)
    geometry: ArtefactGeometry | None = None
    rng: np.random.Generator | None = None
    time_s: float = 0.0
    name: str = "artefact_model"

    def touch(self, move: TouchMove) -> TouchReply:
        self.time_s += move.duration_s
        errors = self.errors(self.time_s) if callable(self.errors) else self.errors
        offsets = self.offsets_um(self.time_s) if callable(self.offsets_um) else self.offsets_um
        try:
            triggered, pos = touch_trigger_position(
                move.artefact, move.c_axis_deg, move.b_axis_deg, np.asarray(move.start_mm),
                np.asarray(move.direction), move.max_travel_mm, errors, offsets,
                self.geometry, self.rng)
        except ValueError as exc:
            raise ProbeBackendError(f"{move.stage}: {exc}") from exc
        return TouchReply(bool(triggered), np.asarray(pos, dtype=float), self.time_s)
