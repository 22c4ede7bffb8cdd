"""Writing a diagnosis: ``report.json``, ``report.md`` with PNG plots, ``diagnosis.rrd``.

Input is the JSON-ready report dict built by :mod:`thermal_twin.diagnose.diagnosis`
plus the time series needed for the plots (:class:`DiagnosisSeries`). Pure I/O; no
rclpy. Plots use matplotlib's Agg backend; the rerun recording is written with
``rerun.RecordingStream.save`` (open it with ``rerun diagnosis.rrd``).
"""
from __future__ import annotations

import json
import math
import pathlib
from dataclasses import dataclass, field

import numpy as np

REQUIRED_CHANNEL_KEYS = ("rmse_before", "rmse_after", "holdout_rmse_before", "holdout_rmse_after")


@dataclass
class DiagnosisSeries:
    """Time series behind the plots: measured, twin before and after, per channel."""

    time_s: np.ndarray
    measured: dict[str, np.ndarray]
    before: dict[str, np.ndarray]
    after: dict[str, np.ndarray]
    holdout_start_s: float
    ccf: dict[str, list] = field(default_factory=dict)   # channel -> [CrossCorrelation]
    dt_s: float = 1.0


def _json_default(o):
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _clean(o):
    """NaN/inf -> None so report.json is strict JSON."""
    if isinstance(o, dict):
        return {k: _clean(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_clean(v) for v in o]
    if isinstance(o, (float, np.floating)) and not math.isfinite(float(o)):
        return None
    return o


def write_json(report: dict, out_dir: pathlib.Path) -> pathlib.Path:
    for ch, d in report.get("channels", {}).items():
        missing = [k for k in REQUIRED_CHANNEL_KEYS if k not in d]
        if missing:
            raise ValueError(f"report channels.{ch}: missing {missing}")
    path = out_dir / "report.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(_clean(report), indent=2, default=_json_default))
    tmp.replace(path)
    return path


def _plot_residuals(series: DiagnosisSeries, windows: list[dict], path: pathlib.Path) -> None:
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    chans = list(series.measured)
    n = len(chans)
    fig, axes = plt.subplots(n, 1, figsize=(11, 1.9 * n + 0.8), sharex=True, squeeze=False)
    th = series.time_s / 3600.0
    for ax, ch in zip(axes[:, 0], chans):
        rb = series.measured[ch] - series.before[ch]
        ra = series.measured[ch] - series.after[ch]
        ax.plot(th, rb, lw=0.8, color="tab:red", label="before")
        ax.plot(th, ra, lw=0.8, color="tab:blue", label="after")
        ax.axvspan(series.holdout_start_s / 3600.0, th[-1], color="0.9", zorder=0)
        for w in windows:
            if ch in w["channels"]:
                ax.axvspan(w["start_s"] / 3600.0, w["end_s"] / 3600.0, color="tab:orange",
                           alpha=0.15, zorder=0)
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylabel(ch, fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(loc="upper left", fontsize=7, ncol=2)
    axes[0, 0].set_title("residual = recording - twin (grey: held-out, orange: located windows)",
                         fontsize=9)
    axes[-1, 0].set_xlabel("time [h]")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _plot_ccf(series: DiagnosisSeries, path: pathlib.Path, per_channel: int = 3) -> bool:
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
    chans = [c for c in series.ccf if series.ccf[c]]
    if not chans:
        return False
    fig, axes = plt.subplots(len(chans), 1, figsize=(9, 1.9 * len(chans) + 0.8), squeeze=False)
    for ax, ch in zip(axes[:, 0], chans):
        for cc in series.ccf[ch][:per_channel]:
            lag_h = cc.lags * series.dt_s / 3600.0
            line, = ax.plot(lag_h, cc.ccf, lw=0.9, label=cc.driver)
            ax.axhline(cc.band, color=line.get_color(), lw=0.5, ls="--")
            ax.axhline(-cc.band, color=line.get_color(), lw=0.5, ls="--")
        ax.set_ylabel(ch, fontsize=8)
        ax.legend(fontsize=6, loc="upper right")
        ax.tick_params(labelsize=7)
    axes[0, 0].set_title("prewhitened cross-correlation of residual (before) with drivers; "
                         "dashed: pointwise 95 % band",
                         fontsize=9)
    axes[-1, 0].set_xlabel("lag [h] (positive: residual follows the driver)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def _fmt(v, nd=3) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}g}"
    return str(v)


def write_markdown(report: dict, series: DiagnosisSeries, out_dir: pathlib.Path) -> pathlib.Path:
    _plot_residuals(series, report.get("windows", []), out_dir / "residuals.png")
    has_ccf = _plot_ccf(series, out_dir / "cross_correlation.png")
    L = [f"# Mismatch diagnosis", "",
         f"- twin: `{report.get('twin', '')}`", f"- recording: `{report.get('recording', '')}`",
         f"- training window: 0 - {report['split']['train_end_s'] / 3600:.1f} h, held out: "
         f"{report['split']['holdout_start_s'] / 3600:.1f} - {report['split']['end_s'] / 3600:.1f} h",
         "", "## Verdict", ""]
    L += _verdict_lines(report)
    L += _channel_lines(report)
    L += _residual_lines(report, has_ccf)
    path = out_dir / "report.md"
    path.write_text("\n".join(L) + "\n")
    return path


def _verdict_lines(report: dict) -> list[str]:
    """Mis-calibrated / missing / unnamed / none, the adoption tests and the notes."""
    L: list[str] = []
    sel = report.get("selected")
    cal = report.get("calibration")
    if cal:
        L += [f"**Calibrated first** ({cal['free_parameters']} existing parameters fitted; held-out "
              f"improvement {cal['holdout_improvement_pct']:.1f} %; {cal['note']}):", ""]
        L += [f"- `{m['name']}`: {_fmt(m['start'])} -> {_fmt(m['value'])} {m['unit']}"
              + (f" ({m['change_pct']:+.0f} %)" if m["change_pct"] is not None else "")
              + f", 95 % interval [{_fmt(m['ci95'][0])}, {_fmt(m['ci95'][1])}]"
              for m in cal["mis_calibrated"][:15]] or ["- no parameter moved beyond its 95 % interval"]
        for key, what in (("adoption_test", "calibration + effects, jointly re-calibrated, against the "
                                            "calibration alone"),
                          ("unnamed_test", "calibrated twin + unnamed discrepancy against the parameters "
                                           "fitted without the prior")):
            t = cal.get(key)
            if t:
                L.append(f"- test, {what}: held-out {t['holdout_improvement_pct']:.1f} % better -> "
                         f"{'passed' if t['passed'] else 'failed: not adopted'}")
        for b in cal.get("at_bound", []):
            L.append(f"- **beyond the builder's tolerance**: `{b['name']}` moved {_fmt(b['start'])} -> "
                     f"{_fmt(b['value'])} {b['unit']}" + (f" ({b['change_pct']:+.0f} %)" if b["change_pct"] is not None
                                                          else "")
                     + f", at its bound [{_fmt(b['bounds'][0])}, {_fmt(b['bounds'][1])}]: missing or changed physics")
        for r in cal.get("residual_structured", [])[:5]:
            L.append(f"- the calibrated residual stays structured on `{r['channel']}` "
                     f"({r['train_rms_over_noise']:.1f} noise sigmas RMS on the training window; the twin as "
                     f"given: {r['given_train_rms_over_noise']:.1f})")
        if report.get("answer") == "beyond-tolerance":
            L += ["", "Answer **beyond-tolerance**: the calibration needed a parameter beyond the builder's "
                      "tolerance and no mechanism of the vocabulary explains it."]
        if report.get("answer") == "none" and cal.get("residual_structured"):
            L += ["", "Answer **none**: the calibrated residual stays structured, but neither the vocabulary "
                      "nor a sparse unnamed term driven by the recorded signals predicts it on held-out data "
                      "(coloured noise, or a driver the recording does not carry)."]
        if report.get("answer") == "mis-calibrated":
            L += ["", "Answer **mis-calibrated**: the existing parameters explain the mismatch; "
                      "nothing is missing."]
        L += ["", "**Missing** (mechanisms added):", ""]
    for u in report.get("unnamed", []):
        L.append(f"- **unnamed** (outside the vocabulary; the nearest vocabulary word, said only as the nearest: "
                 f"{u['nearest_vocabulary_word']}): `{u['formula']}`; {_channel_change(report, u['channel'])}; "
                 f"its terms cut the held-out sum of squares left by a constant offset by "
                 f"{u['holdout_improvement_pct']:.1f} %")
    if not report.get("unnamed") and (sel == "none" or not sel):
        L.append("**none**: no effect of the library improves the held-out fit significantly.")
    elif sel and sel != "none":
        for h in sel:
            ps = ", ".join(f"{k} = {_fmt(p['value'])} {p['unit']}" for k, p in h["params"].items())
            L.append(f"- **{h['effect']}** on `{h['target']}`"
                     + (f" driven by `{h['driver']}`" if h.get("driver") else "")
                     + f": {ps}; held-out improvement {h['holdout_improvement_pct']:.1f} %")
            L += _set_lines(report, h)
        if report.get("augmented_twin"):
            L.append(f"\nAugmented twin: `{report['augmented_twin']}`")
    if report.get("criteria", {}).get("multiple_testing"):
        L.append(f"\nAdoption test: {report['criteria']['multiple_testing']}.")
    for note in report.get("notes", []):
        L.append(f"\n> {note}")
    return L


def _set_lines(report: dict, h: dict) -> list[str]:
    """An adopted effect's indistinguishable set: the others with their held-out figure, and
    what would tell each apart (the channel and regime where the fits differ most)."""
    if not h.get("tell_apart"):
        return []
    held = {f"{x['effect']}:{x['target']}:{x['driver'] or '-'}": x["holdout_improvement_pct"]
            for x in report.get("hypotheses", []) if x.get("round") == h.get("round")}
    L = ["  - indistinguishable on this recording (reported as a set): " + ", ".join(
        f"`{w['other']}` (held-out {held[w['other']]:.1f} %)" if w["other"] in held else f"`{w['other']}`"
        for w in h["tell_apart"])]
    for w in h["tell_apart"]:
        where = (f"they differ most on `{w['channel']}` ({w['difference_rms_sigma']:.2g} noise sigmas RMS)"
                 if w["recorded_channel_tells_apart"] else
                 f"no recorded channel tells them apart (at most {w['difference_rms_sigma']:.2g} noise sigmas "
                 f"RMS, on `{w['channel']}`): a sensor at one of the targets would")
        if w.get("regime"):
            where += (f"; the difference is largest while {w['regime']} "
                      f"({w['regime_difference_rms_sigma']:.2g} noise sigmas RMS): a recording with more of it")
        L.append(f"  - against `{w['other']}`: {where}")
    return L


def _channel_change(report: dict, channel: str) -> str:
    """The channel's held-out RMSE before -> after as the channel table states it."""
    d = report["channels"].get(channel)
    if not d:
        return f"`{channel}` is not in the channel table"
    b, a = d["holdout_rmse_before"], d["holdout_rmse_after"]
    worse = a is not None and b is not None and a > b
    return (f"`{channel}` held-out RMSE {_fmt(b)} -> {_fmt(a)} {d.get('unit', '')}"
            + (" (**worse** than the twin as given)" if worse else ""))


def _channel_lines(report: dict) -> list[str]:
    """The channel table, the located windows and the regime effects."""
    L = ["", "## Channels (RMSE, before -> after; held-out before -> after)", "",
          "| channel | unit | RMSE before | RMSE after | held-out before | held-out after | Ljung-Box p | drift /h |",
          "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for ch, d in report["channels"].items():
        L.append(f"| {ch} | {d.get('unit', '')} | {_fmt(d['rmse_before'])} | {_fmt(d['rmse_after'])} | "
                 f"{_fmt(d['holdout_rmse_before'])} | {_fmt(d['holdout_rmse_after'])} | "
                 f"{_fmt(d.get('ljung_box', {}).get('p_value'))} | "
                 f"{_fmt(d.get('drift', {}).get('slope_per_h'))} |")
    L += ["", "![residuals before and after](residuals.png)", "", "## Located windows", ""]
    if report.get("windows"):
        L += ["| start [h] | end [h] | channels | regime | peak effect |", "| --- | --- | --- | --- | --- |"]
        for w in report["windows"]:
            eff = ", ".join(f"{c}: {_fmt(e['value'])} {e['unit']}" for c, e in w["effect"].items())
            L.append(f"| {w['start_s'] / 3600:.1f} | {w['end_s'] / 3600:.1f} | {', '.join(w['channels'])} "
                     f"| {w['regime']} | {eff} |")
    else:
        L.append("No window stands out of the noise.")
    if report.get("regime_effects"):
        L += ["", "### Regime effects (mean residual inside minus outside)", "",
              "| regime | channel | effect | share of time |", "| --- | --- | --- | --- |"]
        for r in report["regime_effects"][:12]:
            L.append(f"| {r['regime']} | {r['channel']} | {_fmt(r['effect'])} {r['unit']} | "
                     f"{r['share_of_time']:.2f} |")
    return L


def _residual_lines(report: dict, has_ccf: bool) -> list[str]:
    """Residual diagnostics per channel and the ranked hypotheses."""
    L = ["", "## Residual diagnostics", ""]
    for ch, d in report["channels"].items():
        peaks = "; ".join(f"{p['period_h']:.1f} h ({p['power_share'] * 100:.0f} %){' ' + p['label'] if p['label'] else ''}"
                          for p in d.get("spectral_peaks", []))
        xc = "; ".join(f"{c['driver']} r={c['peak_ccf']:.2f} at {c['peak_lag_s'] / 3600:.2f} h"
                       f" (band {c['band_95']:.2f})" for c in d.get("cross_correlation", [])[:3])
        L.append(f"- `{ch}`: white: {d.get('ljung_box', {}).get('white')}; spectral peaks: {peaks or '-'}; "
                 f"tracks: {xc or 'nothing beyond the band'}")
    if has_ccf:
        L += ["", "![cross-correlations](cross_correlation.png)"]
    L += ["", "## Hypotheses (ranked)", "",
          "| rank | effect | target | driver | params | score | held-out improvement | plausible |",
          "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for i, h in enumerate(report.get("hypotheses", [])[:20], 1):
        ps = ", ".join(f"{k}={_fmt(p['value'])} {p['unit']}" for k, p in h["params"].items())
        L.append(f"| {i} | {h['effect']} | {h['target']} | {h.get('driver') or '-'} | {ps} | "
                 f"{_fmt(h['score'])} | {h['holdout_improvement_pct']:.1f} % | "
                 f"{'yes' if h.get('plausible', True) else 'no: ' + h.get('reason', '')} |")
    return L


def write_rerun(series: DiagnosisSeries, out_dir: pathlib.Path) -> pathlib.Path:
    """Measured, twin before/after and residuals per channel as rerun scalar series."""
    import rerun as rr  # heavy: rerun only when writing a recording
    rec = rr.RecordingStream("thermal_comp_diagnose")
    path = out_dir / "diagnosis.rrd"
    rec.save(str(path))
    times = rr.TimeColumn("time", duration=np.asarray(series.time_s, dtype=float))
    for ch in series.measured:
        for kind, data in (("measured", series.measured[ch]), ("twin_before", series.before[ch]),
                           ("twin_after", series.after[ch]),
                           ("residual_before", series.measured[ch] - series.before[ch]),
                           ("residual_after", series.measured[ch] - series.after[ch])):
            rr.send_columns(f"channels/{ch}/{kind}", indexes=[times],
                            columns=rr.Scalars.columns(scalars=np.asarray(data, dtype=float)),
                            recording=rec)
    rec.flush()
    rec.disconnect()
    return path


def write_report(report: dict, series: DiagnosisSeries, out_dir: str | pathlib.Path,
                 rerun: bool = True) -> dict[str, pathlib.Path]:
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": write_json(report, out), "markdown": write_markdown(report, series, out)}
    if rerun:
        paths["rerun"] = write_rerun(series, out)
    return paths
