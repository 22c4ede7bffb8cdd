"""The work of ``thermal-comp learn`` once its arguments are parsed: checks before the long work,
the learning (learn.command), and the report's markdown generated from its JSON."""
from __future__ import annotations

import math
import pathlib
import sys
from typing import Any, Mapping

from thermal_comp_common.bags.recording import BagRecordingError
from thermal_comp_common.components import is_angular
from thermal_comp_common.probe_and_hold import table_5_4_noise
from thermal_twin.calibrate.fit import CalibrationError
from thermal_twin.machine.schema import MachineSpecError, load_machine

from thermal_eval.learn.command import learn
from thermal_eval.learn.current import CurrentPrior, load_current
from thermal_eval.learn.finder import finder_markdown
from thermal_eval.learn.probes import ProbeDataError, cell_recording


def _out_dir(path: str, force: bool) -> pathlib.Path:
    out = pathlib.Path(path)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not force)):
        raise ValueError(f"--out {path}: exists and is not an empty folder (--force writes into it)")
    out.mkdir(parents=True, exist_ok=True)
    probe = out / ".write_check"
    probe.write_text("")
    probe.unlink()
    return out


def _noise(args, components) -> dict[str, float]:
    noise = table_5_4_noise(components)
    for c in components:
        given = args.probe_noise_um_per_m if is_angular(c) else args.probe_noise_um
        if given is not None:
            if not (math.isfinite(given) and given > 0):
                raise ValueError(f"--probe-noise: {given!r} must be a number > 0")
            noise[c] = float(given)
    return noise


def _current(args, machine) -> CurrentPrior | None:
    """The prior the adaptive test is against when one is given (None: the type's)."""
    if args.current_config is not None and args.current_prior is None:
        raise ValueError(f"--current-config {args.current_config}: needs --current-prior")
    if args.current_prior is None:
        return None
    if args.no_prior:
        raise ValueError(f"--current-prior {args.current_prior}: no adaptive test with --no-prior")
    return load_current(args.current_prior, args.current_config, args.twin, machine)


def _fmt(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3g}"


def _tested_against(ref: Mapping[str, Any] | None) -> list[str]:
    """The line naming the prior the adaptive test was against (none without priors)."""
    if not ref:
        return []
    who = ("the prior built on the twin given (--twin: a preset or a twin file)" if ref["source"] == "type"
           else "the prior running now (--current-prior)")
    cfg = f", configuration `{ref['model_config']}`" if ref.get("model_config") else ""
    return [f"Tested against {who}: `{ref['prior']}` (sha256 {ref['sha256']}{cfg}; soft-sensor twin "
            f"`{ref['type_model'] or '-'}`).", ""]


def markdown(rep: Mapping[str, Any]) -> str:
    """report.md, every figure taken from ``rep`` (report.json)."""
    lines = [f"# Learning the unit: {rep['twin']} from {rep['recording']}", "",
             f"Recording {rep['recording_h']:.1f} h; fitted on the probes of the first "
             f"{rep['train_h'] - rep['validate_h']:g} h ({rep['probes']['train']} probing instants), validated on "
             f"the next {rep['validate_h']:g} h ({rep['probes']['validation']}), {rep['probes']['held_out']} held out. "
             f"Calibration {rep['wall_s']['calibration']} s, twin {rep['twin_simulated_h_per_s']} simulated h/s.", "",
             f"**{'Adopted' if rep['adoption']['adopt'] else 'Not adopted'}**: {rep['adoption']['reason']}.", "",
             *_tested_against(rep.get("tested_against")),
             "## What was added", ""]
    st = rep.get("structure") or {}
    lines += [f"- {w['what']} (fit cost {w['fit_cost']:.3g} of the calibrated twin's; validation: "
              f"{w['validation']['reason']})" for w in st.get("words", [])] or [
        "Nothing: no word was better on the validation probes than the calibrated twin."]
    rejected = sorted((t for t in st.get("tried", []) if not t["chosen"]), key=lambda t: t["fit_cost"])[:5]
    if rejected:
        lines += ["", f"Tried and not taken ({len(st['tried'])} fits in {st['wall_s']} s; the five that fitted best):", ""]
        lines += [f"- {t['what']}: fit cost {t['fit_cost']:.3g}; {t['validation'].get('reason', '')}" for t in rejected]
    lines += ["", "## What moved", "", "| parameter | start | learned | change | at tolerance bound |", "|---|---|---|---|---|"]
    for p in rep["parameters"]:
        lines.append(f"| {p['name']} | {_fmt(p['start'])} {p['unit']} | {_fmt(p['value'])} | "
                     f"{_fmt(p['change_pct'])} % | {'yes: beyond the builder tolerance?' if p['at_bound'] else ''} |")
    scores = rep["held_out_scores"]
    comps = list(next(iter(scores.values()))) if scores else []
    lines += ["", "## Held-out probes (RMSE of probe - prediction, made before the probe)", "",
              "| predictor | " + " | ".join(comps) + " |", "|---" * (len(comps) + 1) + "|"]
    for name, row in scores.items():
        lines.append(f"| {name} | " + " | ".join(_fmt(row[c]["rmse"]) for c in comps) + " |")
    lines += ["", "Units: um (E_A0C, E_B0C, E_C0C: um/m). The probe noise is part of every figure alike.",
              *finder_markdown(rep.get("finder")), "", "## Files", ""] + [f"- {k}: `{v}`" for k, v in rep["files"].items()]
    return "\n".join(lines) + "\n"


def run(args) -> int:
    """Exit code: 0 written, 2 bad input (one line)."""
    try:
        if not (math.isfinite(args.train_h) and args.train_h > 0):
            raise ValueError(f"--train-h: {args.train_h!r} must be a number of hours > 0")
        machine = load_machine(args.twin)
        current = _current(args, machine)
        out = _out_dir(args.out, args.force)
        rec, probes = cell_recording(args.recording)
        probes.noise = _noise(args, list(probes.values))
        say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
        rep = learn(machine, rec, probes, out, args.train_h, max_nfev=args.max_nfev, progress=say,
                    build_priors=not args.no_prior, validate_h=args.validate_h, current=current)
    except (ValueError, OSError, MachineSpecError, BagRecordingError, ProbeDataError, CalibrationError) as exc:
        print(f"thermal-comp learn: {exc}", file=sys.stderr)
        return 2
    (out / "report.md").write_text(markdown(rep))
    print(f"wrote {out / 'report.md'}, {out / 'report.json'}, " + ", ".join(rep["files"].values()))
    print(f"learned in {sum(rep['wall_s'].values()):.1f} s (twin {rep['twin_simulated_h_per_s']} simulated h/s); "
          f"words: {'; '.join(w['what'] for w in rep['structure']['words']) or 'none'}")
    return 0
