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
from thermal_comp_common.recording_sources import is_manifest, resolve_runs
from thermal_comp_common.run_splits import run_splits
from thermal_twin.calibrate.fit import CalibrationError
from thermal_twin.machine.schema import MachineSpecError, load_machine

from thermal_eval.learn.command import learn
from thermal_eval.learn.current import CurrentPrior, load_current
from thermal_eval.learn.finder import finder_markdown
from thermal_eval.learn.probes import ProbeDataError, cell_recording
from thermal_eval.learn.report_text import fmt, tested_against_lines
from thermal_eval.learn.runs.command import learn_runs
from thermal_eval.learn.runs.folds import learn_folds
from thermal_eval.learn.runs.report import runs_markdown
from thermal_eval.learn.runs.sources import cell_runs

#: one recording: the probes of the first this many hours train (--train-h)
DEFAULT_TRAIN_H = 48.0


def _out_dir(path: str, force: bool) -> pathlib.Path:
    out = pathlib.Path(path)
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not force)):
        raise ValueError(f"--out {path}: exists and is not an empty folder (--force writes into it)")
    out.mkdir(parents=True, exist_ok=True)
    probe = out / ".write_check"
    probe.write_text("")
    probe.unlink()
    return out


def _drop_if_empty(out: pathlib.Path, created: bool) -> None:
    """A refused learning leaves no folder behind that it made itself and wrote nothing into."""
    if created and out.is_dir() and not any(out.iterdir()):
        out.rmdir()


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


def markdown(rep: Mapping[str, Any]) -> str:
    """report.md, every figure taken from ``rep`` (report.json)."""
    lines = [f"# Learning the unit: {rep['twin']} from {rep['recording']}", "",
             f"Recording {rep['recording_h']:.1f} h; fitted on the probes of the first "
             f"{rep['train_h'] - rep['validate_h']:g} h ({rep['probes']['train']} probing instants), validated on "
             f"the next {rep['validate_h']:g} h ({rep['probes']['validation']}), {rep['probes']['held_out']} held out. "
             f"Calibration {rep['wall_s']['calibration']} s, twin {rep['twin_simulated_h_per_s']} simulated h/s.", "",
             f"**{'Adopted' if rep['adoption']['adopt'] else 'Not adopted'}**: {rep['adoption']['reason']}.", "",
             *tested_against_lines(rep.get("tested_against")),
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
        lines.append(f"| {p['name']} | {fmt(p['start'])} {p['unit']} | {fmt(p['value'])} | "
                     f"{fmt(p['change_pct'])} % | {'yes: beyond the builder tolerance?' if p['at_bound'] else ''} |")
    scores = rep["held_out_scores"]
    comps = list(next(iter(scores.values()))) if scores else []
    lines += ["", "## Held-out probes (RMSE of probe - prediction, made before the probe)", "",
              "| predictor | " + " | ".join(comps) + " |", "|---" * (len(comps) + 1) + "|"]
    for name, row in scores.items():
        lines.append(f"| {name} | " + " | ".join(fmt(row[c]["rmse"]) for c in comps) + " |")
    lines += ["", "Units: um (E_A0C, E_B0C, E_C0C: um/m). The probe noise is part of every figure alike.",
              *finder_markdown(rep.get("finder")), "", "## Files", ""] + [f"- {k}: `{v}`" for k, v in rep["files"].items()]
    return "\n".join(lines) + "\n"


def _plain_recording(sources: list[str]) -> str | None:
    """The path when the sources are one recording file or bag (or a path that does not exist:
    the single-recording learn names it), else None (a folder, a manifest or a glob: resolved)."""
    if len(sources) != 1 or any(ch in sources[0] for ch in "*?["):
        return None
    p = pathlib.Path(sources[0])
    if not p.exists() or (p.is_file() and not is_manifest(p)) or (p / "metadata.yaml").is_file():
        return sources[0]
    return None


def _single_train_h(args) -> float:
    train_h = DEFAULT_TRAIN_H if args.train_h is None else args.train_h
    if not (math.isfinite(train_h) and train_h > 0):
        raise ValueError(f"--train-h: {train_h!r} must be a number of hours > 0")
    return train_h


def _several(args, machine, current, out: pathlib.Path, say) -> dict:
    """The several-run learning (learn.runs): every run read and checked, one learning per fold of
    --runs-split (several folds: learn.runs.folds)."""
    if args.train_h is not None:
        raise ValueError(f"--train-h {args.train_h:g}: splits one recording in time; with several runs the split "
                         "is by run (--runs-split)")
    runs = cell_runs(args.recording, sample_period_s=args.sample_period_s)
    noise = _noise(args, list(runs[0].probes.values))
    for r in runs:
        r.probes.noise = dict(noise)
    folds = run_splits([r.entry for r in runs], args.runs_split)
    how = learn_runs if len(folds) == 1 else learn_folds
    return how(machine, runs, folds[0] if len(folds) == 1 else folds, out, args.validate_h, max_nfev=args.max_nfev,
               progress=say, build_priors=not args.no_prior, current=current)


def run(args) -> int:
    """Exit code: 0 written, 2 bad input (one line)."""
    sources = list(args.recording) if isinstance(args.recording, (list, tuple)) else [args.recording]
    say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
    runs_split = getattr(args, "runs_split", None)
    created = not pathlib.Path(args.out).exists()
    try:
        one = _plain_recording(sources)
        if one is not None:
            _single_train_h(args)
        machine = load_machine(args.twin)
        current = _current(args, machine)
        out = _out_dir(args.out, args.force)
        if one is None:
            entries = resolve_runs(sources)
            one = entries[0].path if len(entries) == 1 else None
        if one is not None and runs_split is not None:
            raise ValueError(f"--runs-split {runs_split}: {sources[0]} is one run; splitting by run needs at "
                             "least two (one recording is split in time: --train-h)")
        if one is None:
            rep = _several(args, machine, current, out, say)
        else:
            rec, probes = cell_recording(one, sample_period_s=args.sample_period_s)
            probes.noise = _noise(args, list(probes.values))
            rep = learn(machine, rec, probes, out, _single_train_h(args), max_nfev=args.max_nfev, progress=say,
                        build_priors=not args.no_prior, validate_h=args.validate_h, current=current)
    except (ValueError, OSError, MachineSpecError, BagRecordingError, ProbeDataError, CalibrationError) as exc:
        _drop_if_empty(pathlib.Path(args.out), created)
        print(f"thermal-comp learn: {exc}", file=sys.stderr)
        return 2
    (out / "report.md").write_text(markdown(rep) if one is not None else runs_markdown(rep))
    print(f"wrote {out / 'report.md'}, {out / 'report.json'}, " + ", ".join(rep["files"].values()))
    if one is None:
        print(f"learned from {sum(r['role'] == 'train' for r in rep['runs'])} runs in {rep['wall_s']['total']:.1f} s; "
              f"{'adopted' if rep['adoption']['adopt'] else 'not adopted'}: {rep['adoption']['reason']}")
        return 0
    print(f"learned in {sum(rep['wall_s'].values()):.1f} s (twin {rep['twin_simulated_h_per_s']} simulated h/s); "
          f"words: {'; '.join(w['what'] for w in rep['structure']['words']) or 'none'}")
    return 0
