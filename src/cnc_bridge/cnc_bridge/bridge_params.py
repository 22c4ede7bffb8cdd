"""The cnc_bridge node's parameters: which apply at run time, which are read-only (pure).

Honest parameters: a parameter is either applied when set at run time (validated, audited,
effective from the next envelope step) or declared read-only, so that a ``set`` is refused
instead of answering "successful" while changing nothing. Only the safety envelope's limits
and ``enable`` are applied at run time (:data:`RUNTIME_ENVELOPE`); everything that shapes a
connection, a transform or a file is fixed for the life of the process (changing it would
need a new configure). Credentials are never parameters (:mod:`cnc_bridge.credentials`).

While the bridge is active a safety limit may only be tightened (:func:`loosening`): one
parameter call must never widen the envelope of a running machine. Widening takes
deactivate (offsets ramp to zero), set, activate -- each step logged and audited.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Mapping

from thermal_comp_common.runtime.node_runtime import Param

from cnc_bridge.error_transform import (ANGULAR_COMPONENTS, CONVENTION_RIGID, CONVENTIONS,
                                        DEFAULT_SPHERE_RADIUS_MM)
from cnc_bridge.safety_envelope import EnvelopeConfig

#: parameter -> EnvelopeConfig field, applied at run time
RUNTIME_ENVELOPE = {
    "abs_limit_um": "abs_limit_um",
    "max_rate_um_per_s": "max_rate_um_per_s",
    "max_step_s": "max_step_s",
    "watchdog_timeout_s": "watchdog_timeout_s",
    "watchdog_hold_s": "watchdog_hold_s",
    "watchdog_ramp_um_per_s": "watchdog_ramp_um_per_s",
    "disable_ramp_um_per_s": "disable_ramp_um_per_s",
}
#: applied at run time besides the envelope fields
RUNTIME_OTHER = ("enable", "abs_limit_um_per_m")
RUNTIME = tuple(RUNTIME_ENVELOPE) + RUNTIME_OTHER
#: runtime limits for which a larger value is a wider (less safe) envelope
_WIDER_IF_LARGER = tuple(RUNTIME_ENVELOPE) + ("abs_limit_um_per_m",)


def loosening(changes: Mapping[str, Any], current: Mapping[str, Any]) -> str | None:
    """Why ``changes`` would widen the envelope set by ``current`` (None: it does not)."""
    for name, new in changes.items():
        old = current.get(name)
        if name not in _WIDER_IF_LARGER or old is None:
            continue
        wider = float(new) > float(old)
        if name == "watchdog_ramp_um_per_s" and float(new) == 0.0 < float(old):
            wider = True        # 0 = hold stale offsets forever
        if wider:
            return (f"parameter '{name}': {old} -> {new} widens the safety envelope; refused while "
                    f"the bridge is active (deactivate, set, activate)")
    return None


def _fixed(*a, **kw) -> Param:
    return Param(*a, read_only=True, **kw)


PARAMS = [
    _fixed("backend", "twin", "where offsets go: twin = published for machine_sim; opcua = a CNC",
           choices=("twin", "opcua")),
    _fixed("autostart", False, "configure and activate at start without a lifecycle manager "
           "(tests, benchmarks); false: wait for configure/activate (the launcher drives them)"),
    _fixed("endpoint", "opc.tcp://127.0.0.1:4840/thermal-comp/cnc", "opcua: server endpoint URL"),
    _fixed("node_map_file", "", "opcua: YAML node-id map (empty = SINUMERIK-like default layout)"),
    _fixed("offset_axes", ["X", "Y", "Z"], "opcua default map: axes with compensation nodes"),
    _fixed("lathe_tools_file", "", "lathe: YAML {tls_component, tools: {T01_X: {intercept_um, gain}}}"),
    _fixed("sphere_radius_mm", DEFAULT_SPHERE_RADIUS_MM,
           "d/2 of eq. 6.3-6.5 (E_R0T reference radius), mm", lo=1.0, hi=5000.0),
    _fixed("htm_convention", CONVENTION_RIGID, "eq. 6.3-6.5 as rigid-body HTM consistent with the "
           "probe cycle (eq. 5.10 signs) or exactly as printed", choices=CONVENTIONS),
    _fixed("htm_origin_mm", [0.0, 0.0, 0.0], "machine X, Y, Z at B = 0 of the point the errors are "
           "defined at (C axis in the probing sphere's centre plane), mm"),
    _fixed("b_pivot_xz_mm", [0.0, 0.0], "X, Z of the B (swivel) axis line, mm"),
    _fixed("positions_required", False, "true: no offsets until X, Y, Z positions are known; "
           "false: axes nobody reports are taken at the HTM origin (position terms vanish), logged once"),
    Param("enable", True, "compensation enabled (false ramps the offsets to zero); applied at run time"),
    Param("abs_limit_um", 30.0, "per-axis absolute offset limit, um; applied at run time",
          lo=0.0, hi=1000.0),
    _fixed("compensation_mode", "axis_offsets",
           "axis_offsets: X/Y/Z offsets at the current axis positions (eq. 6.3-6.5, SINUMERIK "
           "SD43900-like); kinematic: the seven location errors are written as parameters of the "
           "CNC's kinematic model, which applies them at every position (angular errors included); "
           "the 'axes' of AxisOffsets are then the component names, in um or um/m",
           choices=("axis_offsets", "kinematic")),
    Param("abs_limit_um_per_m", 50.0, "kinematic mode: absolute limit of the angular parameters "
          "E_A0C E_B0C E_C0C, um/m (the linear ones use abs_limit_um); applied at run time",
          lo=0.0, hi=10000.0),
    Param("max_rate_um_per_s", 0.5, "maximum offset change per second (cf. MD32760), um/s; "
          "applied at run time", lo=1e-6, hi=1000.0),
    Param("max_step_s", 600.0, "longest time step one update may use for the rate limit, s "
          "(covers a lock-step simulation step; in real time the timer steps every update_period_s); "
          "applied at run time", lo=1e-3, hi=3600.0),
    Param("watchdog_timeout_s", 900.0, "no fresh prediction for this long: hold, s; applied at run time",
          lo=1e-3, hi=1e6),
    Param("watchdog_hold_s", 300.0, "watchdog: hold this long before ramping to zero, s; applied at "
          "run time", lo=0.0, hi=1e6),
    Param("watchdog_ramp_um_per_s", 0.05, "watchdog: ramp to zero at this rate (0 = hold forever), "
          "um/s; applied at run time", lo=0.0, hi=1000.0),
    Param("disable_ramp_um_per_s", 0.5, "ramp rate to zero when disabled or deactivated, um/s; "
          "applied at run time", lo=1e-6, hi=1000.0),
    _fixed("update_period_s", 1.0, "without lock-step: envelope update period between predictions, s",
           lo=1e-3, hi=3600.0),
    _fixed("deactivate_wait_s", 20.0, "wall-clock bridge (no lock-step, no sim time): deactivate "
           "ramps the offsets to zero in real time for at most this long before it returns (the "
           "ramp goes on after that while the node runs); keep it below the launcher's "
           "lifecycle_timeout_s", lo=0.0, hi=600.0),
    _fixed("lockstep", False, "publish SimSync after the offsets answering each prediction"),
    _fixed("max_stamp_ahead_s", 0.0, "refuse predictions and machine states stamped more than this "
           "ahead of the node's clock, s; 0 = 60 s on wall time, 3600 s with use_sim_time",
           lo=0.0, hi=86400.0),
    _fixed("audit_log_path", "", "append-only CSV of every write (empty = no audit log)"),
    _fixed("profile_path", "", "CSV of where each prediction's time went (transform, envelope, CNC "
           "write + read-back, publish, audit, ack), written at exit; empty = not timed (bench graph)"),
    _fixed("connect_timeout_s", 10.0, "opcua: configure fails unless connected within this time, s",
           lo=0.1, hi=600.0),
    _fixed("request_timeout_s", 2.0, "opcua: deadline of one write/read request, s", lo=0.01, hi=60.0),
    _fixed("credentials_file", "", "opcua: YAML {user, password, private_key} readable by its owner "
           "only (mode 600); empty = THERMAL_COMP_OPCUA_USER/PASSWORD/PRIVATE_KEY environment"),
    _fixed("certificate", "", "opcua: client certificate for Basic256Sha256 Sign&Encrypt "
           "(its private key comes with the credentials)"),
    _fixed("server_certificate", "", "opcua: pinned server certificate (empty = use server_trust)"),
    _fixed("server_trust", "", "opcua: folder of trusted server certificates (the trust list)"),
    _fixed("security_required", False, "opcua: refuse any connection without Sign&Encrypt, a user "
           "and a trusted server certificate"),
]


def envelope_config(p: Mapping[str, Any], kinematic: bool) -> EnvelopeConfig:
    """The envelope for parameter values ``p`` (raises EnvelopeConfigError naming a field)."""
    angular = {c: p["abs_limit_um_per_m"] for c in ANGULAR_COMPONENTS} if kinematic else {}
    return EnvelopeConfig(axis_abs_limits_um=angular,
                          **{field: float(p[name]) for name, field in RUNTIME_ENVELOPE.items()})


def changed_envelope(current: EnvelopeConfig, changes: Mapping[str, Any],
                     kinematic: bool) -> EnvelopeConfig | None:
    """``current`` with the runtime parameters in ``changes`` applied (None if none touch it)."""
    fields = {RUNTIME_ENVELOPE[n]: float(v) for n, v in changes.items() if n in RUNTIME_ENVELOPE}
    if "abs_limit_um_per_m" in changes and kinematic:
        fields["axis_abs_limits_um"] = {c: float(changes["abs_limit_um_per_m"])
                                        for c in ANGULAR_COMPONENTS}
    return replace(current, **fields) if fields else None
