"""One bridge update without ROS: predicted errors -> offsets written, confirmed and audited.

Per call of :meth:`BridgeCore.update`, in this order: the errors become commanded offsets at
the current axis positions (:mod:`error_transform`; in kinematic mode the components
themselves), one :class:`~cnc_bridge.safety_envelope.SafetyEnvelope` step, one write through
the backend (:mod:`offset_backend`), the read-back confirmed into the envelope, the caller's
``publish`` (so that the confirmed offsets go out before the audit line's fsync), one audit
line per axis. Switched off (:meth:`BridgeCore.deactivate`), the envelope ramps every offset
to zero; the update that brings the last one there ends the writes. The ROS node and the
fault bench both drive this, so that a bench measures the very path the machine sees.
Problems are handed to ``report`` (kind, text): nothing here logs or raises on bad input.
:attr:`BridgeCore.counters` keeps what an operator asks of a running bridge (writes, the last
confirmed one, clamps, refusals, failures) for the node's ``/diagnostics``.
The watchdog also counts the ``wall`` seconds since a fresh prediction last arrived: a stamp
(forged ahead, or a stalled clock) cannot keep it quiet.

Activation is refused (:meth:`BridgeCore.activate`) while the CNC, at the last start-up,
applied an offset beyond the envelope: bringing it back in one write would be a step far
beyond the rate limit, and ramping it back would keep the envelope violated for hours
(5 mm at 0.5 um/s), so the operator decides (see docs/cnc_bridge.md). A reconnection of the
backend (a restarted CNC) goes through the same rule before the next write
(:meth:`BridgeCore.readopt_after_reconnect`): what is held now is adopted and ramped from, or
the bridge stops writing.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Mapping

from cnc_bridge.audit_log import AuditLog
from cnc_bridge.error_transform import (CONVENTION_RIGID, DEFAULT_SPHERE_RADIUS_MM,
                                        FIVE_AXIS_COMPONENTS, HtmGeometry, LatheToolOffsets,
                                        TransformInputError, offsets_from_errors)
from cnc_bridge.offset_backend import adopt_held_state, reconnect_pending
from cnc_bridge.safety_envelope import (LIMIT_ABSOLUTE, LIMIT_RATE, LIMIT_WATCHDOG,
                                        LIMIT_WRITE_FAILED, HeldAdoption, SafetyEnvelope)
from cnc_bridge.update_profile import UpdateProfile

# Kinds of what :meth:`BridgeCore.update` reports (the node gives each its severity).
TRANSFORM_FAILED = "transform_failed"     # offsets not computable: the envelope holds
ENVELOPE_REFUSED = "envelope_refused"     # a non-finite command: nothing written
WRITE_FAILED = "write_failed"             # the backend refused the write (every axis unconfirmed)
NOT_CONFIRMED = "not_confirmed"           # one axis' write was not read back
POSITIONS_ASSUMED = "positions_assumed"   # X/Y/Z unknown: evaluated at the HTM origin (once)
RAMP_DONE = "ramp_done"                   # switched off and every offset at zero: writes stop
ACTIVATION_REFUSED = "activation_refused" # the CNC holds an offset beyond the envelope: not active

#: um: a held offset this close to the last confirmed one is the same (the read-back's resolution)
HELD_TOLERANCE_UM = 1e-3


@dataclass(frozen=True)
class AppliedAxis:
    """One axis of one write: what was asked, written, read back, and the LIMIT_* flags."""

    axis: str
    commanded_um: float          # the model's command (NaN before the first prediction)
    written_um: float            # the envelope's rate-limited value sent to the CNC
    read_back_um: float | None   # what the CNC answered; None: the write was not confirmed
    applied_um: float            # what the envelope now counts as applied (last confirmed)
    flags: int                   # envelope flags | LIMIT_WRITE_FAILED | start-up adoption flags

    @property
    def confirmed(self) -> bool:
        return self.read_back_um is not None


@dataclass(frozen=True)
class BridgeUpdate:
    """What one update wrote: every axis in the envelope's (sorted) order."""

    t_s: float
    compensation_enabled: bool
    axes: tuple[AppliedAxis, ...]


@dataclass
class BridgeCounters:
    """What the bridge did since its start-up (per axis write = one axis of one update)."""

    writes: int = 0                  # updates that wrote
    clamps: int = 0                  # axis writes flagged absolute (the command was clamped)
    rate_limited: int = 0            # axis writes flagged rate
    write_failures: int = 0          # axis writes not confirmed by read-back
    refusals: int = 0                # commands not applied (transform or envelope refused them)
    activations_refused: int = 0     # activations refused against a held offset
    reconnections: int = 0           # reconnections whose held state was adopted (or refused)
    reconnect_adoptions: int = 0     # axes found holding other than the last confirmed offset
    reconnects_refused: int = 0      # reconnections that found an offset beyond the envelope
    last_confirmed_t: float | None = None                         # stamp of the last confirmed write
    last_confirmed_wall: float | None = None                      # its host time (epoch s)
    last_confirmed_um: dict[str, float] = field(default_factory=dict)   # its read-back per axis
    watchdog: bool = False           # the last write was held or ramped by the watchdog


class BridgeCore:
    """The bridge's write path around one envelope, one backend and an optional audit log."""

    def __init__(self, envelope: SafetyEnvelope, backend, audit: AuditLog | None = None, *,
                 kinematic: bool = False, sphere_radius_mm: float = DEFAULT_SPHERE_RADIUS_MM,
                 lathe: LatheToolOffsets | None = None, htm: HtmGeometry | None = None,
                 convention: str = CONVENTION_RIGID, positions_required: bool = False,
                 profile: UpdateProfile | None = None, now: Callable[[], float] = time.time,
                 report: Callable[[str, str], None] | None = None,
                 wall: Callable[[], float] = time.monotonic):
        """``now``: the clock of audit events (the node passes its ROS clock); ``profile``
        times the phases of an update when the caller began a row; ``wall``: the clock on
        which the watchdog measures the arrival of fresh predictions."""
        self.envelope, self.backend, self.audit = envelope, backend, audit
        self.kinematic = kinematic
        self.sphere_radius_mm, self.lathe, self.convention = sphere_radius_mm, lathe, convention
        self.htm = htm or HtmGeometry()
        self.positions_required = positions_required
        self.profile = profile or UpdateProfile()
        self.now = now
        self.wall = wall
        self._fresh_wall: float | None = None    # when the last fresh prediction arrived
        self._report = report
        self.active = False             # writes follow the predictions
        self.ramping_down = False       # switched off, offsets still on their way to zero
        self.last_update_t: float | None = None
        self.counters = BridgeCounters()
        #: why activation is refused (from the last start-up's adoption); None: it is not
        self.held_refusal: str | None = None
        self._adoption_flags: dict[str, int] = {}
        self._warned_positions = False

    @property
    def writing(self) -> bool:
        """Active, or switched off with offsets still ramping to zero."""
        return self.active or self.ramping_down

    def report(self, kind: str, text: str) -> None:
        if self._report is not None:
            self._report(kind, text)

    def audit_event(self, axis: str, text: str, flags: int = 0) -> None:
        """An audit line that wrote nothing, stamped with ``now()``."""
        if self.audit is not None:
            self.audit.log_event(self.now(), axis, text, flags)

    # ------------------------------------------------------------------ lifecycle
    def adopt_held(self) -> list[HeldAdoption]:
        """Start from what the machine holds (:func:`adopt_held_state`), one audit line per
        axis; the first write of an axis carries the flags its adoption raised."""
        adopted = adopt_held_state(self.envelope, self.backend)
        self._adoption_flags = {a.axis: a.flags for a in adopted if a.flags}
        for a in adopted:
            self.audit_event(a.axis, "start-up: " + a.describe(), a.flags)
        self.held_refusal = _held_refusal(adopted, "the CNC applies ")
        return adopted

    def readopt_after_reconnect(self) -> list[HeldAdoption]:
        """The backend reconnected (:func:`reconnect_pending`): what the CNC holds now is
        adopted by the start-up rule, never overwritten in one write. An axis holding other
        than the last confirmed value (a restarted CNC) is audited ``reconnect|adopted-held``
        and the envelope ramps from it at the rate limit; one applied beyond the envelope
        with compensation on is audited ``reconnect|refused`` and the bridge stops writing
        (inactive, one report line) until the operator configures again. [] if no reconnection."""
        if not reconnect_pending(self.backend):
            return []
        before = self.envelope.applied
        adopted = adopt_held_state(self.envelope, self.backend)
        c = self.counters
        c.reconnections += 1
        for a in adopted:
            moved = abs(a.adopted_um - before.get(a.axis, 0.0)) > HELD_TOLERANCE_UM
            kind = "refused" if a.refused else ("adopted-held" if moved else "as-confirmed")
            c.reconnect_adoptions += kind == "adopted-held"
            if a.flags:       # the next write of the axis carries them, as at start-up
                self._adoption_flags[a.axis] = a.flags
            last = before.get(a.axis)
            self.audit_event(a.axis, f"reconnect|{kind}: " + a.describe() + (
                "" if last is None else f"; last confirmed {last:.3f} um"), a.flags)
        refusal = _held_refusal(adopted, "after a reconnection the CNC applies ")
        if refusal is not None:
            self.held_refusal = refusal
            c.reconnects_refused += 1
            self.active = self.ramping_down = False
            text = "reconnect refused, not writing: " + refusal
            self.audit_event("", text, LIMIT_ABSOLUTE)
            self.report(ACTIVATION_REFUSED, text)
        return adopted

    def activate(self, enabled: bool) -> str | None:
        """Writes follow the predictions; ``enabled`` False keeps the offsets ramping to zero.
        Refused (returns the one-line reason, audited, nothing changes) while the last
        start-up or reconnection found an offset applied beyond the envelope; None when active."""
        self.readopt_after_reconnect()
        if self.held_refusal is not None:
            self.counters.activations_refused += 1
            text = "activate refused: " + self.held_refusal
            self.audit_event("", text, LIMIT_ABSOLUTE)
            self.report(ACTIVATION_REFUSED, text)
            return text
        self.envelope.set_enabled(enabled)
        self.active, self.ramping_down = True, False
        return None

    def deactivate(self) -> bool:
        """Compensation off: offsets ramp to zero on the next updates. True while any is not 0."""
        self.active = False
        self.envelope.set_enabled(False)
        # refused: the held offset is the operator's to bring back, not a ramp of this bridge
        self.ramping_down = self.held_refusal is None and \
            any(abs(v) > 0 for v in self.envelope.applied.values())
        return self.ramping_down

    # ------------------------------------------------------------------ the update
    def silent_s(self) -> float | None:
        """Wall seconds since a fresh prediction last reached an update (None: none yet)."""
        return None if self._fresh_wall is None else self.wall() - self._fresh_wall

    def positions_now(self, errors: Mapping[str, float] | None,
                      positions: Mapping[str, float]) -> dict[str, float]:
        """The backend's axis positions overridden by ``positions``; unless positions are
        required, X/Y/Z still unknown for 5-axis errors are taken at the HTM origin."""
        pos = dict(self.backend.axis_positions())
        pos.update(positions)
        if self.positions_required or errors is None or \
                not any(c in errors for c in FIVE_AXIS_COMPONENTS):
            return pos
        missing = [a for a in ("X", "Y", "Z") if a not in pos]
        if missing:
            origin = self.htm.origin_at_mm(pos.get("B", 0.0))
            for a in missing:
                pos[a] = float(origin["XYZ".index(a)])
            if not self._warned_positions:
                self._warned_positions = True
                self.report(POSITIONS_ASSUMED,
                            f"no position for axis {missing} from machine_state or the CNC: offsets "
                            f"are evaluated at the HTM origin {list(self.htm.origin_mm)} mm")
        return pos

    def commanded(self, errors: Mapping[str, float] | None,
                  positions: Mapping[str, float]) -> dict[str, float] | None:
        """The offsets ``errors`` ask for at ``positions`` (None: no errors yet); raises
        :class:`TransformInputError` when a component or position is missing or not finite."""
        if errors is None:
            return None
        if self.kinematic:          # the CNC's kinematic model takes the location errors themselves
            return dict(errors)
        return offsets_from_errors(errors, self.positions_now(errors, positions),
                                   self.sphere_radius_mm, self.lathe, self.htm, self.convention)

    def update(self, t: float, errors: Mapping[str, float] | None, positions: Mapping[str, float],
               fresh: bool, publish: Callable[[BridgeUpdate], None] | None = None
               ) -> BridgeUpdate | None:
        """One step at time ``t`` [s] with the last good ``errors`` (None: no prediction yet)
        and the reported axis ``positions``; ``fresh``: ``errors`` is a new prediction.
        Returns what was written, or None when nothing was (no axis yet, command refused)."""
        self.readopt_after_reconnect()
        if self.held_refusal is not None and not self.writing:   # held beyond the envelope
            return None
        prof = self.profile
        commanded = None
        try:
            commanded = self.commanded(errors, positions)
        except TransformInputError as exc:     # held: not a fresh prediction for the watchdog
            self.counters.refusals += 1
            self.report(TRANSFORM_FAILED, f"offsets at t={t:.3f}: {exc}; holding")
            fresh = False
        prof.lap("transform")
        try:
            decisions = self.envelope.step(t, commanded, fresh, silent_s=0.0 if fresh else self.silent_s())
        except ValueError as exc:
            self.counters.refusals += 1
            self.report(ENVELOPE_REFUSED, f"offsets at t={t:.3f}: {exc}; holding")
            return None
        if fresh:
            self._fresh_wall = self.wall()
        prof.lap("envelope")
        self.last_update_t = t
        if not decisions:
            return None
        try:
            readback = self.backend.write_offsets({d.axis: d.applied_um for d in decisions})
        except ValueError as exc:            # e.g. an axis without an offset node in the map
            self.report(WRITE_FAILED, f"offsets at t={t:.3f} not written: {exc}")
            readback = {d.axis: None for d in decisions}
        prof.lap("cnc_call")
        prof.note(round_trip_ms=getattr(self.backend, "last_round_trip_s", 0.0) * 1e3,
                  round_trips=getattr(self.backend, "last_round_trips", 0))
        enabled = self.envelope.enabled
        axes = []
        for d in decisions:
            back = readback.get(d.axis)
            self.envelope.confirm(d.axis, back)
            flags = d.flags | (LIMIT_WRITE_FAILED if back is None else 0) | \
                self._adoption_flags.pop(d.axis, 0)
            axes.append(AppliedAxis(d.axis, d.commanded_um, d.applied_um, back,
                                    self.envelope.applied[d.axis], flags))
            if flags & LIMIT_WRITE_FAILED:
                self.report(NOT_CONFIRMED, f"axis {d.axis}: write of {d.applied_um:.3f} um not "
                                           f"confirmed ({getattr(self.backend, 'last_error', '')})")
        update = BridgeUpdate(t, enabled, tuple(axes))
        self._count(update)
        # what the CNC confirmed goes out first; the audit line is on disk before this returns
        if publish is not None:
            publish(update)
        prof.lap("publish")
        if self.audit is not None:
            self.audit.log_write(t, [(a.axis, a.commanded_um, a.read_back_um, a.flags) for a in axes])
        prof.lap("audit")
        if self.ramping_down and all(v == 0.0 for v in self.envelope.applied.values()):
            self.ramping_down = False
            text = "deactivated: every offset is at zero; writes stopped"
            self.audit_event("", text)
            self.report(RAMP_DONE, text)
        return update

    def _count(self, update: BridgeUpdate) -> None:
        c = self.counters
        c.writes += 1
        c.clamps += sum(1 for a in update.axes if a.flags & LIMIT_ABSOLUTE)
        c.rate_limited += sum(1 for a in update.axes if a.flags & LIMIT_RATE)
        c.write_failures += sum(1 for a in update.axes if not a.confirmed)
        c.watchdog = any(a.flags & LIMIT_WATCHDOG for a in update.axes)
        confirmed = {a.axis: a.read_back_um for a in update.axes if a.confirmed}
        if confirmed:
            c.last_confirmed_t, c.last_confirmed_wall = update.t_s, time.time()
            c.last_confirmed_um.update(confirmed)


def _held_refusal(adopted: list[HeldAdoption], lead: str) -> str | None:
    """The one line refusing to write against offsets applied beyond the envelope (None: none)."""
    refused = [a for a in adopted if a.refused]
    if not refused:
        return None
    return (lead + "; ".join(f"{a.axis} = {a.held_um:.3f} um, {a.refused}" for a in refused)
            + "; nothing written. Bring the held offset within the limit or switch the axis' "
              "compensation off on the CNC, then configure again")
