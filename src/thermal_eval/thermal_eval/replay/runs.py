"""``thermal-comp replay RUN RUN ...``: every run replayed alone (a fresh model, or the same
prior, per run: its own start reference and probing clock), each with its own JSON and PNG
(``OUT.<run>.json``), and ``OUT`` holding every run's figures and the pooled ones: per component
P99 and RMS over the scored rows of every run together, compensated and uncompensated."""
from __future__ import annotations

import copy
import json
import math
import pathlib
import sys
from typing import Any, Callable, Sequence

import numpy as np

from thermal_comp_common import metrics
from thermal_comp_common.recording_sources import RunEntry
from thermal_eval.replay.summary import scored_rows


def pooled_components(collected: Sequence[tuple[str, Any, dict]], score_from_h: float | None) -> dict[str, Any]:
    """Per component, the scored rows of every run together: P99 and RMS with and without the
    compensation, and how many runs and rows."""
    parts: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for _, result, _ in collected:
        rows = scored_rows(result, score_from_h)
        for c in result.components:
            e = np.asarray(result.true[c], float)[rows]
            a = np.asarray(result.predicted[c], float)[rows]
            a = np.where(np.isfinite(a), a, 0.0)          # no prediction = no compensation
            ok = np.isfinite(e)
            parts.setdefault(c, []).append((e[ok], a[ok]))
    out = {}
    for c, p in parts.items():
        e = np.concatenate([x for x, _ in p])
        a = np.concatenate([y for _, y in p])
        if not e.size:
            out[c] = {"runs": len(p), "rows": 0}
            continue
        z = np.zeros_like(e)
        out[c] = {"runs": len(p), "rows": int(e.size), "p99": metrics.p99(e, a), "rms": metrics.e_rms(e, a),
                  "p99_uncompensated": metrics.p99(e, z), "rms_uncompensated": metrics.e_rms(e, z)}
    return out


def _safe(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_safe(x) for x in v]
    return v


def run_many(args, entries: Sequence[RunEntry], replay_one: Callable[..., int]) -> int:
    """Replay every run with ``replay_one(args_of_the_run, collect=...)``; the first failing run's
    exit code stops it. Then the combined JSON and the pooled table."""
    out = pathlib.Path(args.json)
    if out.is_file() and not args.force:
        print(f"thermal-comp replay: --json {str(out)!r} exists (use --force to overwrite it)", file=sys.stderr)
        return 3
    collected: list[tuple[str, Any, dict]] = []
    runs = []
    for k, e in enumerate(entries):
        a = copy.copy(args)
        a.recording = e.path
        a.json = str(out.with_name(f"{out.stem}.{e.name}.json"))
        a.png = None
        print(f"replay: run {k + 1}/{len(entries)} {e.name!r}", file=sys.stderr, flush=True)
        n = len(collected)
        rc = replay_one(a, collect=collected)
        if rc != 0:
            return rc
        name, _, summary = collected[n]
        runs.append({"name": e.name, "path": e.path, "unit": e.unit, "programme": e.programme, "date": e.date,
                     "json": a.json, **{k2: summary[k2] for k2 in ("p99_lin_um", "p99_ang_um_per_m", "q_prod_pct",
                                                                    "probing_cycles", "calibration_h", "duration_h")}})
    pooled = pooled_components(collected, args.score_from_h)
    out.write_text(json.dumps(_safe({"model": args.model, "runs": runs, "pooled": pooled}), indent=2) + "\n")
    print(f"pooled over {len(entries)} runs (scored rows of every run together):")
    print(f"{'component':>12} {'runs':>5} {'rows':>7} {'P99 uncomp':>11} {'P99 comp':>9} {'RMS uncomp':>11} {'RMS comp':>9}")
    for c, v in pooled.items():
        if v["rows"]:
            print(f"{c:>12} {v['runs']:>5} {v['rows']:>7} {v['p99_uncompensated']:>11.2f} {v['p99']:>9.2f} "
                  f"{v['rms_uncompensated']:>11.2f} {v['rms']:>9.2f}")
    print(f"wrote {out}")
    return 0
