"""``thermal-comp replay REC --model talc|agp|cd [--config YAML] [--set key=value ...] --json OUT``
``[--errors-topic TOPIC] [--temperatures-topic TOPIC] [--score-from-h H]``

The virtual experiment of the Blaser thesis §6.3: replay a recording (the twin's CSV, a bag
folder or an ``.mcap`` file) through an adaptive model, without ROS, probing only when the
model asks, with realistic probe noise (Table 5.4: 0.25 um linear, 1.2 um/m angular, 0.25 um
resolution). Prints a Table 6.5-style table, writes the indicators as JSON and a PNG of true
error, compensation and residual per component. A model component is named as its error column
(``z_um``) or without its ``_um``; ``--score-from-h`` scores a held-out window only.
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys
import time

from thermal_eval.baseline_beside import beside_probe_and_hold
from thermal_eval.replay_summary import (PROBE_NOISE_ANGULAR_UM_PER_M, PROBE_NOISE_LINEAR_UM, PROBE_RESOLUTION_UM,
                             ReplayInputError, build_model, format_table, load_config_file, load_replay_recording,
                             parse_overrides, probe_noise, summarise)

MODEL_KINDS = ("talc", "agp", "cd")


def _with_prior(kind: str, config: dict, path: str):
    from talc_model.prior import PriorError, load_prior
    from talc_model.prior_agp import model_from_prior
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


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thermal-comp replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("recording", metavar="REC", help="twin CSV, bag folder or .mcap file")
    ap.add_argument("--model", required=True, choices=MODEL_KINDS, help="model kind")
    ap.add_argument("--config", metavar="YAML", help="model parameters (a mapping; `preset:` for TALC)")
    ap.add_argument("--set", metavar="KEY=VALUE", action="append", default=[], dest="overrides",
                    help="override one parameter (YAML value, e.g. post_cp_interval_h=inf); repeatable")
    ap.add_argument("--json", metavar="OUT", required=True, help="write the indicators to this JSON file")
    ap.add_argument("--png", metavar="OUT", help="plot (default: the JSON path with .png)")
    ap.add_argument("--probe-noise-um", type=float, default=PROBE_NOISE_LINEAR_UM,
                    help="probe noise sigma on linear components, um (default %(default)s, Table 5.4)")
    ap.add_argument("--probe-noise-um-per-m", type=float, default=PROBE_NOISE_ANGULAR_UM_PER_M,
                    help="probe noise sigma on angular components, um/m (default %(default)s, Table 5.4)")
    ap.add_argument("--probe-resolution-um", type=float, default=PROBE_RESOLUTION_UM,
                    help="quantisation of probe readings (default %(default)s; 0 = none)")
    ap.add_argument("--seed", type=int, default=0, help="probe-noise seed (default %(default)s)")
    ap.add_argument("--hours", type=float, default=None, help="replay only the first HOURS of the recording")
    ap.add_argument("--errors-topic", default="errors/ground_truth", metavar="TOPIC",
                    help="bag topic of the measured errors (default %(default)s; `import-csv --errors measured` "
                         "writes errors/measured)")
    ap.add_argument("--temperatures-topic", default="temperatures", metavar="TOPIC",
                    help="bag topic of the temperatures (default %(default)s)")
    ap.add_argument("--score-from-h", type=float, default=None, metavar="H",
                    help="score only the rows from H hours after the first row (a held-out window; "
                         "default: the whole compensation part)")
    ap.add_argument("--prior", metavar="PRIOR", help="start the model (talc, agp or cd) from this prior of its kind (thermal-comp prior --model KIND, or --from-state of another machine); its model_kind must match --model")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        for name in ("probe_noise_um", "probe_noise_um_per_m", "probe_resolution_um"):
            v = getattr(args, name)
            if not (math.isfinite(v) and v >= 0):
                raise ReplayInputError(f"--{name.replace('_', '-')}: {v!r} must be a finite number >= 0")
        if args.hours is not None and not (math.isfinite(args.hours) and args.hours > 0):
            raise ReplayInputError(f"--hours: {args.hours!r} must be a finite number > 0")
        config = load_config_file(args.config) if args.config else {}
        config.update(parse_overrides(args.overrides))
        model = build_model(args.model, config) if not args.prior else _with_prior(args.model, config, args.prior)
        rec = load_replay_recording(args.recording, args.errors_topic, args.temperatures_topic)
        stop = None
        if args.hours is not None:
            stop = int((rec.time_s <= rec.time_s[0] + 3600.0 * args.hours).sum())
        from thermal_eval.virtual_experiment import plot_virtual_experiment, run_virtual_experiment
        noise = probe_noise(model.component_names, args.probe_noise_um, args.probe_noise_um_per_m)
        t0 = time.perf_counter()
        result = run_virtual_experiment(rec, model, probe_noise_um=noise,
                                        probe_resolution_um=args.probe_resolution_um, seed=args.seed,
                                        stop=stop, progress=not args.no_progress, compute_metrics=False)
        wall = time.perf_counter() - t0
        status = model.status(float(result.time_s[-1]))
        summary = summarise(result, status, args.score_from_h)
    except (ReplayInputError, ValueError) as exc:
        print(f"thermal-comp replay: {exc}", file=sys.stderr)
        return 2
    beside, text = beside_probe_and_hold(result, summary["q_prod_pct"], noise, args.probe_resolution_um, seed=args.seed)
    out = {"recording": str(args.recording), "model": args.model, "config": config,
           "errors_topic": args.errors_topic, "temperatures_topic": args.temperatures_topic,
           "probe_noise": {"linear_um": args.probe_noise_um, "angular_um_per_m": args.probe_noise_um_per_m,
                           "resolution_um": args.probe_resolution_um, "seed": args.seed},
           "prior": args.prior, **summary, "probe_and_hold": beside, "replay_s": round(wall, 3)}
    json_path = pathlib.Path(args.json)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(_json_safe(out), indent=2) + "\n")
    png = pathlib.Path(args.png) if args.png else json_path.with_suffix(".png")
    plot_virtual_experiment(result, png, title=f"{args.model} {pathlib.Path(args.recording).name}")
    print(format_table(summary, title=f"{args.model} on {args.recording} ({wall:.1f} s)"))
    print(text)
    print(f"wrote {json_path} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
