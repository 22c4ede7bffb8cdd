"""One replay (virtual experiment, Blaser thesis §6.3) summarised like the thesis's Table 6.5.

Shared by ``thermal-comp replay`` and ``thermal-comp sweep``; no rclpy. Loads the recording,
parses model parameters, sets the probe noise (thesis Table 5.4) and computes the indicators
over the compensation part; the choices are explained in docs/replay_sweep.md ("Replay").
"""
from __future__ import annotations

import math
import pathlib
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from talc_model.adaptive_model import PHASE_CALIBRATION, is_angular, make_model
from thermal_comp_common import metrics
from thermal_comp_common.bags.recording import check_recording, load_recording
from thermal_comp_common.recording_csv import RecordingError
from thermal_eval.replay.virtual_experiment import ReplayColumns

#: Probe repeatability (k = 1) and resolution of the sphere cycle, thesis Table 5.4 (defined once,
#: in thermal_comp_common.probe_and_hold).
from thermal_comp_common.probe_and_hold import TABLE_5_4_NOISE_ANGULAR_UM_PER_M as PROBE_NOISE_ANGULAR_UM_PER_M  # noqa: E402
from thermal_comp_common.probe_and_hold import TABLE_5_4_NOISE_LINEAR_UM as PROBE_NOISE_LINEAR_UM  # noqa: E402
from thermal_comp_common.probe_and_hold import TABLE_5_4_RESOLUTION_UM as PROBE_RESOLUTION_UM  # noqa: E402


class ReplayInputError(ValueError):
    """Bad replay input (file, parameter); the message names the key / path and value."""


def load_replay_recording(path: str | pathlib.Path, errors_topic: str = "errors/ground_truth",
                          temperatures_topic: str = "temperatures", sample_period_s: float | None = None):
    """A ``Recording`` from a twin CSV (``sample_period_s``: one without a time column), a bag
    folder or an ``.mcap`` file; a bad file is a :class:`ReplayInputError` naming it."""
    try:
        return load_recording(path, temperatures_topic, errors_topic, sample_period_s)
    except (OSError, ValueError) as exc:
        msg = str(exc)
        raise ReplayInputError(msg if msg.startswith("recording ") else f"recording {str(path)!r}: {msg}") from None


def check_replay_recording(rec, components: Sequence[str], stop: int | None = None) -> None:
    """Refuse what calibrate and diagnose refuse too (:func:`~thermal_comp_common.bags.recording.check_recording`):
    too few rows, infinite or absurd values, an error column of a model component without enough
    finite values (``stop``: only the first rows are replayed). A component without any error
    column is left for the replay to name."""
    errors = ReplayColumns.from_recording(rec).errors
    required = [errors[c] for c in components if c in errors]
    try:
        check_recording(rec, required, [c for c in rec.names("sensor") if c not in required], stop)
    except RecordingError as exc:
        raise ReplayInputError(str(exc)) from None


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["key=value", ...]`` -> mapping; values parsed as YAML (``inf``, ``[a, b]``, ``1e3``)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ReplayInputError(f"--set {item!r}: expected key=value")
        try:
            value = yaml.safe_load(raw) if raw.strip() else ""
        except yaml.YAMLError as exc:
            raise ReplayInputError(f"--set {key}: value {raw!r} is not valid YAML ({exc})") from None
        if isinstance(value, str) and value.strip().lower() in ("inf", "+inf", "infinity"):
            value = math.inf
        out[key] = value
    return out


def load_config_file(path: str | pathlib.Path) -> dict[str, Any]:
    """A model configuration YAML file: a mapping of model parameters."""
    path = pathlib.Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ReplayInputError(f"--config {str(path)!r}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise ReplayInputError(f"--config {str(path)!r}: not valid YAML ({exc})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ReplayInputError(f"--config {str(path)!r}: expected a mapping of parameters, "
                               f"got {type(data).__name__}")
    return data


def build_model(kind: str, config: Mapping[str, Any]):
    """``make_model`` with its configuration errors turned into :class:`ReplayInputError`."""
    try:
        return make_model(kind, dict(config))
    except (ValueError, TypeError) as exc:
        raise ReplayInputError(f"model {kind!r}: {exc}") from None


def probe_noise(components: Sequence[str], linear_um: float = PROBE_NOISE_LINEAR_UM,
                angular_um_per_m: float = PROBE_NOISE_ANGULAR_UM_PER_M) -> dict[str, float]:
    """Per-component probe noise (k = 1): angular components in um/m, the others in um."""
    return {c: (angular_um_per_m if is_angular(c) else linear_um) for c in components}


def scored_rows(result, score_from_h: float | None = None) -> np.ndarray:
    """The rows scored: the compensation part, and with ``score_from_h`` only from that many hours
    after the recording's first row (a held-out window: the rows the model has not been
    calibrated on)."""
    t = np.asarray(result.time_s, float)
    comp = np.asarray(result.phase) != PHASE_CALIBRATION
    if score_from_h is None:
        return comp
    if not (isinstance(score_from_h, (int, float)) and math.isfinite(score_from_h) and score_from_h >= 0):
        raise ReplayInputError(f"--score-from-h: {score_from_h!r} must be a finite number >= 0")
    if t.size and t[0] + 3600.0 * score_from_h > t[-1]:
        raise ReplayInputError(f"--score-from-h: {score_from_h!r} h is after the recording's end "
                               f"({(t[-1] - t[0]) / 3600.0:.2f} h)")
    return comp & (t >= t[0] + 3600.0 * score_from_h) if t.size else comp


def summarise(result, status, score_from_h: float | None = None) -> dict[str, Any]:
    """Table 6.5-style indicators of a ``VirtualExperimentResult`` and the model's final status.

    ``status`` is a ``ModelStatusData``. Scored: :func:`scored_rows`. Components without a
    finite sample there get NaN indicators (and are left out of P99_lin / P99_ang).
    """
    phase = np.asarray(result.phase)
    comp = phase != PHASE_CALIBRATION
    scored = scored_rows(result, score_from_h)
    t = result.time_s
    per: dict[str, dict[str, float]] = {}
    p99c: dict[str, float] = {}
    for c in result.components:
        e = np.asarray(result.true[c], float)[scored]
        applied = np.asarray(result.predicted[c], float)[scored]
        applied = np.where(np.isfinite(applied), applied, 0.0)   # no prediction = no compensation
        ok = np.isfinite(e)
        row = {"unit": "um/m" if is_angular(c) else "um", "p99": math.nan, "rms": math.nan,
               "p99_uncompensated": math.nan, "rms_uncompensated": math.nan}
        if ok.any():
            zero = np.zeros(int(ok.sum()))
            row.update(p99=metrics.p99(e[ok], applied[ok]), rms=metrics.e_rms(e[ok], applied[ok]),
                       p99_uncompensated=metrics.p99(e[ok], zero), rms_uncompensated=metrics.e_rms(e[ok], zero))
            p99c[c] = row["p99"]
        per[c] = row
    lin = [c for c in result.components if not is_angular(c)]
    ang = [c for c in result.components if is_angular(c)]
    calibration_h = float(t[comp][0] - t[0]) / 3600.0 if comp.any() else math.nan
    return {"components": per,
            "p99_lin_um": metrics.p99_group(p99c, lin),
            "p99_ang_um_per_m": metrics.p99_group(p99c, ang),
            "q_prod_pct": float(status.q_prod_pct),
            "probing_cycles": int(status.probing_cycles),
            "failed_probing_cycles": int(status.failed_probing_cycles),
            "no_good_phases": int(status.no_good_phases),
            "parameter_updates": int(status.parameter_updates),
            "calibration_h": calibration_h,
            "compensation_steps": int(comp.sum()),
            "scored_steps": int(scored.sum()),
            "scored_from_h": score_from_h,
            "duration_h": float(t[-1] - t[0]) / 3600.0 if t.size else 0.0,
            "final_phase": status.phase}


def _headline(v: float) -> str:
    """A headline figure, or "n/a (nothing scored)": a NaN is never printed as a result."""
    return f"{v:.2f}" if math.isfinite(v) else "n/a (nothing scored)"


def format_table(summary: Mapping[str, Any], title: str = "") -> str:
    """Plain-text table like the thesis's Table 6.5 (P99 uncompensated / compensated / reduction)."""
    comps = list(summary["components"])
    per = summary["components"]

    def cell(v: float) -> str:
        return f"{v:9.2f}" if math.isfinite(v) else "      n/a"
    lines = []
    if title:
        lines.append(title)
    cp_h = summary['calibration_h']
    lines.append(f"Q_prod {summary['q_prod_pct']:.2f} %, CP "
                 + (f"{cp_h:.2f} h" if math.isfinite(cp_h) else "not ended") + ", "
                 f"{summary['probing_cycles']} probing cycles, {summary['no_good_phases']} no-good phases, "
                 f"{summary['parameter_updates']} parameter updates")
    lines.append("".ljust(20) + "".join(c.rjust(9) for c in comps))
    lines.append("unit".ljust(20) + "".join(per[c]["unit"].rjust(9) for c in comps))
    lines.append("P99 uncompensated".ljust(20) + "".join(cell(per[c]["p99_uncompensated"]) for c in comps))
    lines.append("P99 compensated".ljust(20) + "".join(cell(per[c]["p99"]) for c in comps))
    red = []
    for c in comps:
        u, k = per[c]["p99_uncompensated"], per[c]["p99"]
        red.append(100.0 * (1.0 - k / u) if math.isfinite(u) and math.isfinite(k) and u > 0 else math.nan)
    lines.append("Reduction %".ljust(20) + "".join(cell(r) for r in red))
    lines.append("RMS compensated".ljust(20) + "".join(cell(per[c]["rms"]) for c in comps))
    lines.append(f"P99_lin {_headline(summary['p99_lin_um'])} um, "
                 f"P99_ang {_headline(summary['p99_ang_um_per_m'])} um/m")
    if summary.get("scored_from_h") is not None:
        lines.append(f"scored from {summary['scored_from_h']:g} h ({summary['scored_steps']} steps)")
    if summary["compensation_steps"] == 0:
        lines.append("the model never left its calibration phase: nothing compensated to score (n/a)")
    return "\n".join(lines)
