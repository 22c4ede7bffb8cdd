"""Where the wall time of a lock-step instant goes: the stages of the round trip, from the
publication times of each instant's messages (DDS source timestamps, one host's clock:
thermal_comp.demo.monitor).

Per instant t_k the critical path is machine_sim -> ``twin/sensor_readings`` -> sensors ->
``temperatures`` -> model -> ``errors/predicted`` -> bridge (CNC write, read back) ->
``offsets`` -> the last ``sim_sync`` acknowledgement -> machine_sim steps the twin and
publishes t_{k+1}. :func:`stage_breakdown` splits each instant's cycle into those stages and
says how much of the run's wall time each took (``bench graph`` prints it);
:func:`latency_breakdown` splits the temperature -> offsets latency further with the bridge's
own timing of each prediction (cnc_bridge.update_profile). Pure: no rclpy.
"""
from __future__ import annotations

import numpy as np

#: The stages of one instant, in order along the critical path: (name, from, to). Names of
#: events: topic names, "ack" (the last participant's sim_sync for the instant) and "next"
#: (the next instant's ``twin/sensor_readings``).
STAGES = (
    ("twin -> temperatures (sensors)", "twin/sensor_readings", "temperatures"),
    ("temperatures -> prediction (model)", "temperatures", "errors/predicted"),
    ("prediction -> offsets (bridge, CNC write)", "errors/predicted", "offsets"),
    ("offsets -> last ack (probing, recorder)", "offsets", "ack"),
    ("last ack -> next instant (machine_sim)", "ack", "next"),
)


def instant_events(arrivals: dict[tuple[str, int], float], acks: dict[tuple[str, int], float],
                   participants: list[str]) -> dict[int, dict[str, float]]:
    """Per instant (stamp ns): event name -> publication time (s), for instants with every event.

    ``arrivals[(topic, stamp_ns)]`` is the first publication of a topic's message for an
    instant, ``acks[(node, stamp_ns)]`` the first acknowledgement of a participant."""
    twin = sorted(s for (topic, s) in arrivals if topic == "twin/sensor_readings")
    out: dict[int, dict[str, float]] = {}
    for k, s in enumerate(twin[:-1]):
        ev = {topic: arrivals.get((topic, s)) for _, topic, _ in STAGES[:3]}
        ev["offsets"] = arrivals.get(("offsets", s))
        ack_times = [acks.get((n, s)) for n in participants]
        ev["ack"] = max(ack_times) if ack_times and None not in ack_times else None
        ev["next"] = arrivals[("twin/sensor_readings", twin[k + 1])]
        if None not in ev.values():
            out[s] = ev
    return out


def stage_breakdown(events: dict[int, dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per stage: median and p99 (ms) over the instants and share (%) of the summed cycle time;
    plus the whole cycle ("instant (sum)"). Stages that overlap a little (an acknowledgement that
    came before the offsets) count as 0 in that instant, so the shares may add to under 100."""
    if not events:
        return {}
    rows = list(events.values())
    cycle = np.array([r["next"] - r["twin/sensor_readings"] for r in rows])
    total = float(cycle.sum())
    out: dict[str, dict[str, float]] = {}
    for name, a, b in STAGES:
        d = np.maximum(np.array([r[b] - r[a] for r in rows]), 0.0)
        out[name] = {"median_ms": round(float(np.median(d)) * 1e3, 2),
                     "p99_ms": round(float(np.percentile(d, 99)) * 1e3, 2),
                     "share_pct": round(100.0 * float(d.sum()) / total, 1) if total > 0 else 0.0}
    out["instant (sum)"] = {"median_ms": round(float(np.median(cycle)) * 1e3, 2),
                            "p99_ms": round(float(np.percentile(cycle, 99)) * 1e3, 2),
                            "share_pct": 100.0}
    return out


def ack_breakdown(arrivals: dict[tuple[str, int], float], acks: dict[tuple[str, int], float],
                  participants: list[str]) -> dict[str, dict[str, float]]:
    """Per participant: median and p99 (ms) from an instant's ``twin/sensor_readings`` to its
    acknowledgement, and how often (%) it was the last to acknowledge (who holds the graph)."""
    twin = {s: t for (topic, s), t in arrivals.items() if topic == "twin/sensor_readings"}
    delays: dict[str, list[float]] = {n: [] for n in participants}
    last: dict[str, int] = {n: 0 for n in participants}
    instants = 0
    for s, t0 in twin.items():
        times = {n: acks.get((n, s)) for n in participants}
        if None in times.values():
            continue
        instants += 1
        for n, t in times.items():
            delays[n].append(t - t0)
        last[max(times, key=times.get)] += 1
    return {n: {"median_ms": round(float(np.median(d)) * 1e3, 2),
                "p99_ms": round(float(np.percentile(d, 99)) * 1e3, 2),
                "last_pct": round(100.0 * last[n] / instants, 1)}
            for n, d in delays.items() if d}


#: The temperature-to-offsets latency of one instant, in order along its path: (name, profile
#: column). model: temperatures -> errors/predicted publications; DDS hop: that publication ->
#: the bridge's callback; " of it": parts of the CNC call (the round trip as the client's
#: event loop times it; the rest is the call's own work around it: the lock, the loop's
#: start and stop in the node's thread, and other tasks the loop served meanwhile).
#: From the DDS publication of ``temperatures`` to that of the answering ``offsets``; the
#: bridge publishes them after the CNC confirmed the write (write status and read-back), and
#: writes its audit line after that (``audit``, outside the latency, before the lock-step ack).
LATENCY_PARTS = (
    ("model: DDS hop + step", None),
    ("DDS hop into the bridge", None),
    ("parse + transform", "transform_ms"),
    ("envelope step", "envelope_ms"),
    ("CNC write + read-back", "cnc_call_ms"),
    (" of it: OPC UA round trip", "round_trip_ms"),
    (" of it: around the round trip", None),
    ("publication", "publish_ms"),
)


def _figures(values_ms: list[float], total_ms: float) -> dict[str, float]:
    d = np.maximum(np.asarray(values_ms, dtype=float), 0.0)
    return {"median_ms": round(float(np.median(d)), 3), "p99_ms": round(float(np.percentile(d, 99)), 3),
            "share_pct": round(100.0 * float(d.sum()) / total_ms, 1) if total_ms > 0 else 0.0}


def latency_breakdown(arrivals: dict[tuple[str, int], float],
                      bridge_rows: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Per part of the temperature -> offsets latency (:data:`LATENCY_PARTS`): median, p99 (ms)
    and share (%) of the summed latency, over the instants the bridge profiled
    (cnc_bridge.update_profile rows, joined by stamp); plus the whole latency, the audit line
    (after the publication) and how many predictions needed a second OPC UA read."""
    parts: dict[str, list[float]] = {name: [] for name, _ in LATENCY_PARTS}
    total, audit, reread = [], [], 0
    for row in bridge_rows:
        s = int(row["stamp_ns"])
        t_temp = arrivals.get(("temperatures", s))
        t_pred = arrivals.get(("errors/predicted", s))
        t_off = arrivals.get(("offsets", s))
        if None in (t_temp, t_pred, t_off) or "cnc_call_ms" not in row:
            continue
        total.append((t_off - t_temp) * 1e3)
        parts[LATENCY_PARTS[0][0]].append((t_pred - t_temp) * 1e3)
        parts[LATENCY_PARTS[1][0]].append((row["received_wall_s"] - t_pred) * 1e3)
        for name, column in LATENCY_PARTS[2:]:
            if column is not None:
                parts[name].append(row.get(column, 0.0))
        parts[LATENCY_PARTS[6][0]].append(row["cnc_call_ms"] - row.get("round_trip_ms", 0.0))
        audit.append(row.get("audit_ms", 0.0))
        reread += row.get("round_trips", 1) > 1
    if not total:
        return {}
    whole = float(np.sum(total))
    out = {name: _figures(v, whole) for name, v in parts.items()}
    out["latency (sum)"] = _figures(total, whole)
    out["audit line (after it)"] = _figures(audit, whole)
    out["second reads"] = {"count": reread, "of": len(total)}
    return out
