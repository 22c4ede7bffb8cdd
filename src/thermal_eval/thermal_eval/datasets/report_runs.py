"""The table of ``evaluate`` on several runs: pooled figures per role, then one line per held-out run."""
from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table

from thermal_comp_common import plain_output
from thermal_eval.evaluate.baselines import BASELINES


def _fig(c: dict, prefix: str = "") -> str:
    v = [c.get(f"{prefix}{k}") for k in ("mae_um", "rmse_um", "p99_um")]
    return "-" if v[0] is None else " / ".join(f"{x:.3f}" for x in v)


def _cell(c: dict | None, ratio_key: str | None) -> str:
    if not c:
        return "-"
    r = c.get(ratio_key) if ratio_key else None
    return _fig(c) + (f" x{r:.2f}" if isinstance(r, (int, float)) else "")


def pooled_table(pooled: dict[str, Any], title: str, base: str) -> Table:
    chans = list(dict.fromkeys(c for m in pooled["open_loop"].values() for c in m))
    t = Table(title=title)
    t.add_column("mode")
    t.add_column("model")
    for c in chans:
        t.add_column(c, justify="right")
    for name, cells in pooled["open_loop"].items():
        t.add_row("open loop", name, *[_cell(cells.get(c), f"ratio_to_{base}") for c in chans])
    for name, cells in pooled["adaptive"].items():
        t.add_row("adaptive", name, *[_cell(cells.get(c), "ratio_to_hold") for c in chans])
        t.add_row("", f"  hold {name}'s probes", *[_fig(cells[c], "hold_own_probes_") if c in cells else "-"
                                                   for c in chans])
    return t


def _mean_mae(cells: dict | None) -> float | None:
    v = [c["mae_um"] for c in (cells or {}).values() if c.get("mae_um") is not None]
    return sum(v) / len(v) if v else None


def per_run_table(figures: dict[str, Any], models: list[str], base: str) -> Table:
    """One line per held-out run: channel-mean MAE of the baseline and of ``models`` (open loop,
    adaptive and holding the adaptive model's probes)."""
    t = Table(title="per held-out run: MAE (um, mean over channels)")
    for col in ("fold", "run", "role", "unit", "programme", base):
        t.add_column(col)
    for m in models:
        t.add_column(f"{m} open loop", justify="right")
        t.add_column(f"{m} adaptive (hold)", justify="right")
    fmt = lambda v: "-" if v is None else f"{v:.3f}"   # noqa: E731
    for fold in figures["folds"]:
        for r in fold["per_run"]:
            p = r["pooled"]
            row = [fold["name"], r["run"], r["role"], r["unit"], r["programme"], fmt(_mean_mae(p["open_loop"].get(base)))]
            for m in models:
                ad = p["adaptive"].get(m)
                hold = None if not ad else _mean_mae({c: {"mae_um": v["hold_own_probes_mae_um"]} for c, v in ad.items()})
                row += [fmt(_mean_mae(p["open_loop"].get(m))), f"{fmt(_mean_mae(ad))} ({fmt(hold)})"]
            t.add_row(*row)
    return t


def print_runs(figures: dict[str, Any], models: list[str] | None = None, console: Console | None = None) -> None:
    console = console or plain_output.console(min_width=160)
    base = figures["ratio_baseline"]
    if figures.get("run_start"):
        console.print(figures["run_start"]["said"])
    for role, pooled in figures["pooled"].items():
        n = sum(1 for f in figures["folds"] for r in f["per_run"] if r["role"] == role)
        title = (f"pooled over {n} held-out {role} runs: MAE / RMSE / P99 (um); x: MAE ratio to {base} (open loop) "
                 "or to holding the same probes (adaptive)")
        if "vs_truth" not in pooled:
            console.print(pooled_table(pooled, title, base))
            continue
        console.print(pooled_table(pooled, f"{title}; AGAINST THE RECORDING (noisy readings)", base))
        console.print(pooled_table(pooled["vs_truth"], f"{title}; AGAINST THE TRUTH (noise-free displacement; the "
                                                       "models and holding used the same noisy probes)", base))
    if models is None:       # the models beside the named baseline: not the plain baselines
        plain = {b.name for b in BASELINES}
        models = [m for m in next(iter(figures["pooled"].values()))["open_loop"] if m not in plain][:3]
    console.print(per_run_table(figures, models, base))


def _f(v: float | None, fmt: str = ".3f") -> str:
    return "-" if v is None else format(v, fmt)


def _ratio_cell(a: float | None, b: float | None, bold: bool = True) -> str:
    """Two ratios to holding (unseen runs / unseen unit); ``bold``: those above 0.5 (the target)."""
    return " / ".join("-" if v is None else (f"**{v:.3f}**" if bold and v > 0.5 else f"{v:.3f}") for v in (a, b))


def _fleet_rows(fig: dict[str, Any], truth: bool) -> list[str]:
    """The table rows of one scoring (the recording's, or the truth's) of one preset's fleet."""
    def part(role: str) -> dict:
        s = fig.get(role, {})
        return s.get("vs_truth", {}) if truth else s
    runs, unit = part("unseen_runs"), part("unseen_unit")
    base = fig["evaluation"]["ratio_baseline"]
    worst = fig.get("worst_run_ratio_to_hold_vs_truth" if truth else "worst_run_ratio_to_hold", {})
    rows = []
    for name, ol in runs.get("open_loop", {}).items():
        ou = unit.get("open_loop", {}).get(name, {})
        a, b = runs.get("adaptive", {}).get(name), unit.get("adaptive", {}).get(name)
        cells = [f"`{name}`", f"{_f(ol['mean_mae_um'])} / {_f(ou.get('mean_mae_um'))} "
                 f"(x{_f(ol[f'worst_channel_ratio_to_{base}'], '.2f')} / "
                 f"x{_f(ou.get(f'worst_channel_ratio_to_{base}'), '.2f')})"]
        if a and b:
            w = worst.get(name, {})
            cells += [f"{_f(a['mean_mae_um'])} ({_f(a['hold_mean_mae_um'])})",
                      f"{_f(b['mean_mae_um'])} ({_f(b['hold_mean_mae_um'])})",
                      _ratio_cell(a["worst_channel_ratio_to_hold"], b["worst_channel_ratio_to_hold"]),
                      _ratio_cell(w.get("unseen_runs"), w.get("unseen_unit"), bold=False)]
        else:
            cells += ["-"] * 4
        rows.append(cells)
    return rows


def fleet_markdown(preset: str, fig: dict[str, Any], seed: int) -> str:
    """One preset's fleet figures (``bench evaluate`` JSON ``fleet.<preset>``) as a markdown
    table: per model the figures against the noisy recording, then the same against the truth
    when the fleet has one; bold: a pooled worst channel above 0.5 x holding."""
    plan, rs = fig["plan"], fig["run_start"]
    head = (f"**{preset}**, fleet seed {seed} ({plan['units']} units x {plan['runs_per_unit']} runs of "
            f"{plan['hours']:g} h, probe noise {plan['probe_noise_um']:g} um, runs start: {rs['mode']}, rest "
            f"{rs['rest_h']:g} h; evaluation {fig['seconds']} s)")
    base = fig["evaluation"]["ratio_baseline"]
    has_truth = "vs_truth" in fig.get("unseen_unit", {})
    cols = ["model", f"open loop MAE unseen runs / unseen unit (worst channel x {base})",
            "adaptive 1/h MAE (hold) unseen runs", "unseen unit", "worst channel x hold (runs / unit)",
            "worst single run x hold (runs / unit)"]
    rec, tru = _fleet_rows(fig, False), (_fleet_rows(fig, True) if has_truth else [])
    if has_truth:
        cols += [f"vs truth: {c}" for c in cols[1:]]
        rec = [r + t[1:] for r, t in zip(rec, tru)]
    lines = [head + (": MAE um (channel mean); the first five columns are scored against the noisy recording, "
                     "the columns 'vs truth' against the noise-free displacement" if has_truth else ":"), "",
             "| " + " | ".join(cols) + " |", "| " + " | ".join(["---"] * len(cols)) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rec]
    return "\n".join(lines)
