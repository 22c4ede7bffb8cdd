"""Regression replays of bags through the model, compared with golden results stored beside them.

:func:`replay` turns a bag back into the model's inputs and runs the virtual experiment;
:func:`compare` lists the differences in words, so a failing test says what changed. The
folder layout (``regression.yaml``, ``golden.json``) and how to re-generate goldens:
docs/bags.md ("Regression bags"). No rclpy here.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
import yaml

from talc_model.adaptive_model import make_model
from thermal_comp_common.bags import msg_definitions
from thermal_comp_common.bags.reader import BagContents, read_bag, read_metadata
from thermal_comp_common.bags.recording import BagRecordingError, bag_to_recording

from thermal_eval.replay.virtual_experiment import run_virtual_experiment

SPEC_FILE = "regression.yaml"
GOLDEN_FILE = "golden.json"
#: absolute / relative tolerance on predicted values and uncertainties (um or um/m): the
#: replay is deterministic; the slack only absorbs floating-point differences between
#: BLAS builds.
ATOL = 1e-6
RTOL = 1e-6
MAX_DIFF_LINES = 25


class RegressionError(ValueError):
    """A regression bag or its spec is unusable; the message names the file and key."""


@dataclass
class RegressionSpec:
    model_kind: str
    model_config: dict
    errors_topic: str = "errors/ground_truth"
    temperatures_topic: str = "temperatures"
    probe_noise_um: float = 0.0
    probe_resolution_um: float = 0.0
    seed: int = 0
    probed_components: list[str] | None = None
    extra: dict = field(default_factory=dict)

    @classmethod
    def load(cls, path: pathlib.Path) -> "RegressionSpec":
        try:
            data = yaml.safe_load(path.read_text())
        except OSError as exc:
            raise RegressionError(f"{path}: {exc.strerror}") from None
        if not isinstance(data, dict):
            raise RegressionError(f"{path}: expected a mapping")
        for key in ("model_kind", "model_config"):
            if key not in data:
                raise RegressionError(f"{path}: missing key '{key}'")
        known = set(cls.__dataclass_fields__) - {"extra"}
        unknown = sorted(set(data) - known - {"description"})
        if unknown:
            raise RegressionError(f"{path}: unknown key(s) {unknown}")
        return cls(**{k: v for k, v in data.items() if k in known})


def replay(bag: str | os.PathLike, spec: RegressionSpec | None = None, progress: bool = False) -> dict:
    """Replay a regression bag through its model; the JSON-ready result (golden format)."""
    bag = pathlib.Path(bag)
    spec = spec or RegressionSpec.load(bag / SPEC_FILE)
    contents = read_bag(bag)
    if contents.damage:
        raise RegressionError(f"{bag}: damaged bag: {contents.damage}")
    rec = bag_to_recording(contents, spec.temperatures_topic, spec.errors_topic)
    model = make_model(spec.model_kind, spec.model_config)
    res = run_virtual_experiment(rec, model, probed_components=spec.probed_components,
                                 probe_noise_um=spec.probe_noise_um,
                                 probe_resolution_um=spec.probe_resolution_um, seed=spec.seed,
                                 progress=progress)

    def clean(a):   # 10 significant digits: far below the comparison tolerance
        return [None if not math.isfinite(v) else float(f"{v:.10g}") for v in np.asarray(a, dtype=float)]

    return {
        "bag": bag.name, "model_kind": spec.model_kind, "steps": int(res.time_s.size),
        "time_s": clean(res.time_s),
        "predicted": {c: clean(res.predicted[c]) for c in res.components},
        "std": {c: clean(res.std[c]) for c in res.components},
        "phase": [str(p) for p in res.phase],
        "probe_times_s": [float(t) for t in res.probe_times_s],
        "final_status": json.loads(json.dumps(res.final_status, default=str)),
        "metrics": json.loads(json.dumps(res.metrics, default=float)),
    }


def _close(a, b) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return abs(a - b) <= ATOL + RTOL * abs(b)


def compare(now: Mapping, golden: Mapping) -> list[str]:
    """Differences between a replay result and the golden one, in words (empty: equal)."""
    out: list[str] = []
    if now.get("steps") != golden.get("steps"):
        out.append(f"steps: golden {golden.get('steps')}, now {now.get('steps')}")
    t = golden.get("time_s", [])
    tg, tn = set(golden.get("probe_times_s", [])), set(now.get("probe_times_s", []))
    for x in sorted(tg - tn)[:MAX_DIFF_LINES]:
        out.append(f"probing at t={x:g} s: golden probed, now it does not")
    for x in sorted(tn - tg)[:MAX_DIFF_LINES]:
        out.append(f"probing at t={x:g} s: now probes, golden did not")
    for key, label in (("predicted", "predicted"), ("std", "uncertainty")):
        g, n = golden.get(key, {}), now.get(key, {})
        if set(g) != set(n):
            out.append(f"{label} components: golden {sorted(g)}, now {sorted(n)}")
        for comp in sorted(set(g) & set(n)):
            bad = [k for k, (a, b) in enumerate(zip(n[comp], g[comp])) if not _close(a, b)]
            if bad:
                k = bad[0]
                when = f"t={t[k]:g} s" if k < len(t) and t[k] is not None else f"step {k}"
                worst = max(bad, key=lambda i: abs((n[comp][i] or 0) - (g[comp][i] or 0)))
                out.append(f"{comp} {label} differs at {len(bad)} of {len(g[comp])} steps; first at "
                           f"{when}: golden {g[comp][k]}, now {n[comp][k]}; largest at "
                           f"t={t[worst]:g} s: golden {g[comp][worst]}, now {n[comp][worst]}")
    pg, pn = golden.get("phase", []), now.get("phase", [])
    changed = [k for k, (a, b) in enumerate(zip(pn, pg)) if a != b]
    if changed:
        k = changed[0]
        out.append(f"phase differs at {len(changed)} steps; first at t={t[k]:g} s: golden {pg[k]!r}, now {pn[k]!r}")
    if len(out) > MAX_DIFF_LINES:
        out = out[:MAX_DIFF_LINES] + [f"... and {len(out) - MAX_DIFF_LINES} more differences"]
    return out


def golden_path(bag: str | os.PathLike) -> pathlib.Path:
    return pathlib.Path(bag) / GOLDEN_FILE


def write_golden(bag: str | os.PathLike, result: Mapping) -> pathlib.Path:
    path = golden_path(bag)
    tmp = path.with_suffix(".json.tmp")
    lines = [f"{json.dumps(k)}: {json.dumps(result[k], sort_keys=True, separators=(',', ':'))}"
             for k in sorted(result)]   # one line per key: small, and diffs stay readable
    tmp.write_text("{\n" + ",\n".join(lines) + "\n}\n")
    tmp.replace(path)
    return path


def regression_bags(root: str | os.PathLike) -> list[pathlib.Path]:
    """Bag folders under ``root`` that carry a regression.yaml."""
    return sorted(p.parent for p in pathlib.Path(root).glob(f"*/{SPEC_FILE}"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m thermal_eval.replay.bag_regression", description=
                                 "Replay regression bags through their model and compare with (or, "
                                 "with --update, re-write) golden.json beside each bag.")
    ap.add_argument("bags", nargs="+", help="bag folders with regression.yaml, or folders holding such "
                    "bags (e.g. bags)")
    ap.add_argument("--update", action="store_true", help="write golden.json from this replay")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    failed = 0
    targets: list[pathlib.Path] = []
    for arg in map(pathlib.Path, args.bags):
        found = [arg] if (arg / SPEC_FILE).is_file() else (regression_bags(arg) if arg.is_dir() else [])
        if not found:
            print(f"{arg}: neither a regression bag (no {SPEC_FILE}) nor a folder of them", file=sys.stderr)
            failed += 1
        targets += found
    for b in targets:
        try:
            read_metadata(b)
            result = replay(b, progress=sys.stderr.isatty())
        except ValueError as exc:
            print(f"{b}: {exc}", file=sys.stderr)
            failed += 1
            continue
        if args.update:
            print(f"{b}: wrote {write_golden(b, result)} ({result['steps']} steps, "
                  f"{len(result['probe_times_s'])} probing cycles)")
            continue
        gp = golden_path(b)
        if not gp.is_file():
            print(f"{b}: no {GOLDEN_FILE}; create it with --update", file=sys.stderr)
            failed += 1
            continue
        diff = compare(result, json.loads(gp.read_text()))
        print(f"{b}: " + ("matches golden" if not diff else "DIFFERS from golden:\n  " + "\n  ".join(diff)))
        failed += bool(diff)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
