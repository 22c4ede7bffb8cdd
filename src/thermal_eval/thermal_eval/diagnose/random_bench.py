"""``thermal-comp bench diagnose --random N --seed S [--calibrate] [--jobs J]``: fresh drawn cases.

Draws cases ``0..N-1`` of seed ``S`` (:mod:`thermal_eval.diagnose.random_cases`), diagnoses each
against its unmodified preset (with ``--calibrate``: calibrate first) on a local pool of ``J``
processes (the project's task engine), prints one progress line per finished case (answer,
verdict, diagnosis wall time, cases per minute so far) and writes
``OUT_DIR/diagnose_random_s{S}_n{N}[_cal].json`` (every outcome and the figures) and ``.md``
(the tables of docs/diagnose.md, generated from the JSON by :func:`markdown`; :func:`rescore`
renders a finished run's JSON again).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

from thermal_comp_common.runtime.engine_options import add_jobs_argument
from thermal_comp_common.runtime.task_engine import EngineSpec, map_tasks
from thermal_eval.diagnose.random_score import judge, run_case, score


def parse(extra: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="thermal-comp bench diagnose --random")
    ap.add_argument("--random", type=int, required=True, metavar="N", help="number of drawn cases")
    ap.add_argument("--seed", type=int, default=1000, help="seed S (case i of seed S is drawn alone)")
    ap.add_argument("--first", type=int, default=0, help="first case index (cases first .. first+N-1)")
    ap.add_argument("--calibrate", action="store_true", help="diagnose --calibrate (calibrate first)")
    add_jobs_argument(ap, "drawn cases")
    a = ap.parse_args(extra)
    for name in ("random", "jobs"):
        if getattr(a, name) < 1:
            ap.error(f"--{name}: {getattr(a, name)} must be >= 1")
    if a.seed < 0 or a.first < 0:
        ap.error(f"--seed/--first: {a.seed}/{a.first} must be >= 0")
    return a


def _line(k: int, n: int, o: dict, elapsed: float) -> str:
    j = judge(o)
    truth = "+".join(o["true_keys"] + o["oov"]) or "none"
    ans = o["answer"] + (f" {o['selected']}" if o.get("selected") else "")
    verdict = ("exact" if j["exact"] else "type" if j["first"] else "right" if j["right"] else "MISS")
    return (f"[{k}/{n}] {o['label'].split(' ')[0]} {o['twin']}:{o['scenario']} size {o['size_measured']:.1f} "
            f"truth {truth} -> {ans} [{verdict}, extra {j['extra']}] diagnosis {o['wall_s']:.1f} s "
            f"({o['rows']} rows); {60.0 * k / elapsed:.2f} cases/min, load {os.getloadavg()[0]:.1f}")


def run(args: argparse.Namespace) -> dict:
    a = parse([x for x in (getattr(args, "extra", None) or [])])
    items = [(a.seed, i) for i in range(a.first, a.first + a.random)]
    print(f"diagnose --random: {a.random} cases of seed {a.seed} from index {a.first}, "
          f"calibrate={a.calibrate}, {a.jobs} job(s)", flush=True)
    t0 = time.perf_counter()
    outcomes = []
    for k, (_, o) in enumerate(map_tasks(run_case, {"calibrate": a.calibrate}, items,
                                         EngineSpec("local", workers=a.jobs)), start=1):
        outcomes.append(o)
        print(_line(k, a.random, o, time.perf_counter() - t0), flush=True)
    outcomes.sort(key=lambda o: o["index"])
    wall = time.perf_counter() - t0
    figures = score(outcomes, wall_s=wall)
    meta = {"seed": a.seed, "first": a.first, "n": a.random, "calibrate": a.calibrate, "jobs": a.jobs,
            "wall_s": round(wall, 1), "load_average_1min": round(os.getloadavg()[0], 1)}
    out_dir = pathlib.Path(getattr(args, "out_dir", None) or "bench_out")
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = out_dir / f"diagnose_random_s{a.seed}_f{a.first}_n{a.random}{'_cal' if a.calibrate else ''}"
    stem.with_suffix(".json").write_text(json.dumps({"meta": meta, "figures": figures, "outcomes": outcomes},
                                                    indent=1, default=float))
    stem.with_suffix(".md").write_text(markdown(meta, figures))
    print(f"written {stem}.json and {stem}.md", flush=True)
    flat = {f"diagnose.random.{k}": v for k, v in figures.items() if not isinstance(v, dict)}
    flat["diagnose.random.wall_s"] = meta["wall_s"]
    return flat


def rescore(paths: list, out: str | pathlib.Path | None = None) -> str:
    """The markdown of finished runs' JSON (runs of one seed and mode over contiguous case
    ranges are pooled), scored again: the outcomes are the data, so a new breakdown needs no new
    diagnosis. Written to ``out`` (default: beside the single JSON) and returned."""
    runs = [json.loads(pathlib.Path(p).read_text()) for p in paths]
    metas = [r["meta"] for r in runs]
    if len({(m["seed"], m["calibrate"]) for m in metas}) != 1:
        raise ValueError(f"paths: {paths!r} mix seeds or modes; pool runs of one seed and mode only")
    outcomes = [o for r in runs for o in r["outcomes"]]
    wall = sum(m["wall_s"] for m in metas)
    meta = {**metas[0], "first": min(m["first"] for m in metas), "n": len(outcomes), "wall_s": round(wall, 1),
            "load_average_1min": max(m["load_average_1min"] for m in metas)}
    md = markdown(meta, score(outcomes, wall_s=wall))
    target = pathlib.Path(out) if out else pathlib.Path(paths[0]).with_suffix(".md")
    target.write_text(md)
    return md


def _cell(v) -> str:
    return "-" if v is None else (f"{v:g}" if isinstance(v, float) else str(v))


def markdown(meta: dict, fig: dict) -> str:
    """The run's tables, every figure taken from ``fig`` (the JSON's ``figures``)."""
    mode = "diagnose --calibrate" if meta["calibrate"] else "diagnose"
    lines = [f"**{mode}**, seed {meta['seed']}, cases {meta['first']}-{meta['first'] + meta['n'] - 1} "
             f"({fig['cases']} cases, {meta['jobs']} jobs, {meta['wall_s']:g} s wall, "
             f"{_cell(fig.get('cases_per_minute'))} cases/min, load {meta['load_average_1min']:g})", "",
             "| figure | value |", "| --- | --- |"]
    lines += [f"| {k} | {_cell(v)} |" for k, v in fig.items() if not isinstance(v, dict)]
    lines += ["", "| true type (single effect) | n | true effect first % | exact target % |", "| --- | --- | --- | --- |"]
    lines += [f"| {t} | {d['n']} | {_cell(d['first_pct'])} | {_cell(d['exact_pct'])} |" for t, d in fig["per_type"].items()]
    lines += ["", "| measured size (effect RMS / noise RMS) | n | true effect first % | exact target % |",
              "| --- | --- | --- | --- |"]
    lines += [f"| {b} | {d['n']} | {_cell(d['first_pct'])} | {_cell(d['exact_pct'])} |" for b, d in fig["per_size"].items()]
    if "per_condition" in fig:
        lines += ["", "| recording condition | n | right answer % | `unnamed` on cases without out-of-vocabulary physics |",
                  "| --- | --- | --- | --- |"]
        lines += [f"| {c} | {d['n']} | {_cell(d['right_pct'])} | {d['unnamed_without_oov']} |"
                  for c, d in fig["per_condition"].items()]
    answers = sorted({a for row in fig["confusion"].values() for a in row})
    lines += ["", "Confusion (rows: concealed, first effect of a two-effect case; columns: answer)", "",
              "| concealed | " + " | ".join(answers) + " |", "| --- " * (len(answers) + 1) + "|"]
    lines += [f"| {t} | " + " | ".join(str(row.get(a, 0)) or "0" for a in answers) + " |"
              for t, row in fig["confusion"].items()]
    return "\n".join(lines) + "\n"
