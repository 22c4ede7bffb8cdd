"""The work of ``thermal-comp replay`` (:mod:`thermal_eval.replay.cli` parses the arguments): the
virtual experiment of one model on one recording, its table, JSON and plot."""
from __future__ import annotations

import json
import math
import pathlib
import sys
import time

from thermal_eval.replay.baseline_beside import beside_probe_and_hold
from thermal_comp_common.recording_sources import DatasetError, is_manifest, resolve_runs
from thermal_eval.replay.runs import run_many
from thermal_eval.replay.config_keys import ConfigKeyError, canonical_config, replay_warnings
from thermal_eval.replay.summary import (ReplayInputError, build_model, check_replay_recording, format_table,
                                         load_config_file, load_replay_recording, parse_overrides, probe_noise,
                                         summarise)
from thermal_eval.replay.virtual_experiment import ReplayColumns, plot_virtual_experiment, run_virtual_experiment


def _with_prior(kind: str, config: dict, path: str):
    # the priors' code: only with --prior
    from talc_model.prior.common import PriorError
    from talc_model.prior.dispatch import model_from_prior
    from talc_model.prior.talc import load_prior
    try:
        return model_from_prior(kind, config, load_prior(path))
    except PriorError as exc:
        raise ReplayInputError(str(exc)) from None


def _json_safe(value):
    """NaN / inf -> None / "inf" so the JSON file stays standard."""
    if isinstance(value, float):
        if math.isnan(value):
            return None
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return value
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def _writable(path: str, flag: str) -> pathlib.Path:
    """``path`` once it is known that a file can be written there (tried, before the replay's long
    work; a file made for the trial is removed): ReplayInputError naming the flag otherwise."""
    p = pathlib.Path(path)
    if p.is_dir():
        raise ReplayInputError(f"{flag} {path!r}: is a folder, expected a file path")
    existed = p.exists()
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "a"):
            pass
    except OSError as exc:
        raise ReplayInputError(f"{flag} {path!r}: cannot write there ({exc.strerror or exc})") from None
    if not existed:
        p.unlink()
    return p


def _refuse_existing(args) -> str | None:
    """The overwrite rule of every output: an existing file is refused unless --force."""
    paths = [("--json", args.json), ("--png", args.png or str(pathlib.Path(args.json).with_suffix(".png")))]
    for flag, p in paths:
        if pathlib.Path(p).is_file() and not args.force:
            return f"{flag} {p!r} exists (use --force to overwrite it)"
    return None


def _several(args):
    """The runs the REC arguments name when they are more than one recording (several, a folder,
    a glob or a manifest), else None (one recording file or bag folder: today's path)."""
    recs = [args.recording] if isinstance(args.recording, str) else list(args.recording)
    if len(recs) == 1:
        p = pathlib.Path(recs[0])
        bag = p.is_dir() and (p / "metadata.yaml").is_file()
        missing = not p.exists() and not any(ch in recs[0] for ch in "*?[")
        if bag or missing or (p.is_file() and not is_manifest(p)):
            args.recording = recs[0]
            return None
    entries = resolve_runs(recs)
    if len(entries) == 1:
        args.recording = entries[0].path
        return None
    return entries


def run(args, collect: list | None = None) -> int:
    """Replay as the parsed arguments say; the exit code (0 written, 2 bad input, 3 output exists:
    the inputs are checked first, then an existing output is refused before the replay runs).
    Several recordings: every run alone, then the pooled figures (:mod:`thermal_eval.replay.runs`);
    ``collect`` receives (recording, result, summary) of a run."""
    try:
        entries = _several(args)
    except DatasetError as exc:
        print(f"thermal-comp replay: {exc}", file=sys.stderr)
        return 2
    if entries is not None:
        return run_many(args, entries, run)
    try:
        png_path = _writable(args.png, "--png") if args.png else None
        json_path = _writable(args.json, "--json")
        for name in ("probe_noise_um", "probe_noise_um_per_m", "probe_resolution_um"):
            v = getattr(args, name)
            if not (math.isfinite(v) and v >= 0):
                raise ReplayInputError(f"--{name.replace('_', '-')}: {v!r} must be a finite number >= 0")
        if args.hours is not None and not (math.isfinite(args.hours) and args.hours > 0):
            raise ReplayInputError(f"--hours: {args.hours!r} must be a finite number > 0")
        config = load_config_file(args.config) if args.config else {}
        config.update(parse_overrides(args.overrides))
        rec = load_replay_recording(args.recording, args.errors_topic, args.temperatures_topic, args.sample_period_s)
        config, notes = canonical_config(args.model, config, rec.names("error"))
        model = build_model(args.model, config) if not args.prior else _with_prior(args.model, config, args.prior)
        stop = None
        if args.hours is not None:
            stop = int((rec.time_s <= rec.time_s[0] + 3600.0 * args.hours).sum())
        check_replay_recording(rec, model.component_names, stop)
        named = ReplayColumns.from_recording(rec).errors
        refused = _refuse_existing(args) if all(c in named for c in model.component_names) else None
        if refused:       # (a component without a column is named by the replay itself: exit 2)
            print(f"thermal-comp replay: {refused}", file=sys.stderr)
            return 3
        for note in notes:
            print(f"warning: {note}", file=sys.stderr)
        for warning in rec.warnings:
            print(f"warning: {warning}", file=sys.stderr)
        noise = probe_noise(model.component_names, args.probe_noise_um, args.probe_noise_um_per_m)
        t0 = time.perf_counter()
        result = run_virtual_experiment(rec, model, probe_noise_um=noise,
                                        probe_resolution_um=args.probe_resolution_um, seed=args.seed,
                                        stop=stop, progress=not args.no_progress, compute_metrics=False)
        wall = time.perf_counter() - t0
        status = model.status(float(result.time_s[-1]))
        summary = summarise(result, status, args.score_from_h)
    except (ReplayInputError, ConfigKeyError, ValueError) as exc:
        print(f"thermal-comp replay: {exc}", file=sys.stderr)
        return 2
    for note in replay_warnings(summary):
        print(f"warning: {note}", file=sys.stderr)
    beside, text = beside_probe_and_hold(result, summary["q_prod_pct"], noise, args.probe_resolution_um, seed=args.seed)
    out = {"recording": str(args.recording), "model": args.model, "config": config,
           "errors_topic": args.errors_topic, "temperatures_topic": args.temperatures_topic,
           "probe_noise": {"linear_um": args.probe_noise_um, "angular_um_per_m": args.probe_noise_um_per_m,
                           "resolution_um": args.probe_resolution_um, "seed": args.seed},
           "prior": args.prior, **summary, "probe_and_hold": beside, "replay_s": round(wall, 3),
           "warnings": replay_warnings(summary)}
    json_path.write_text(json.dumps(_json_safe(out), indent=2) + "\n")
    if collect is not None:
        collect.append((str(args.recording), result, summary))
    png = png_path or json_path.with_suffix(".png")
    plot_virtual_experiment(result, png, title=f"{args.model} {pathlib.Path(args.recording).name}")
    print(format_table(summary, title=f"{args.model} on {args.recording} ({wall:.1f} s)"))
    print(text)
    print(f"wrote {json_path} and {png}")
    return 0
