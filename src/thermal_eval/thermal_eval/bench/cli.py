"""Run the performance benchmarks and print and save every figure with the machine it ran on.

Suites come from the entry-point group ``thermal_comp.bench`` (``suite = module:function``,
``function(args) -> dict`` of figures). ``thermal-comp bench`` runs them all;
``thermal-comp bench twin bridge --json out.json`` runs some. Speed and memory are only ever
measured here, never asserted by tests.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import pathlib
import platform
import sys
import time
import traceback
from importlib.metadata import entry_points
from typing import Any

GROUP = "thermal_comp.bench"


def suites() -> dict:
    return {ep.name: ep for ep in entry_points(group=GROUP)}


def machine_info() -> dict[str, Any]:
    """What the figures were measured on."""
    import psutil  # only when suites run: --help stays fast
    cpu = platform.processor() or ""
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "hostname": platform.node(),
        "cpu": cpu,
        "logical_cpus": os.cpu_count(),
        "memory_gib": round(psutil.virtual_memory().total / 2**30, 1),
        "os": platform.platform(),
        "python": platform.python_version(),
        "date_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }


def _flatten(prefix: str, value: Any, out: list[tuple[str, Any]]) -> None:
    if isinstance(value, dict):
        for k, v in value.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), v, out)
    else:
        out.append((prefix, value))


def print_figures(name: str, figures: dict) -> None:
    from rich.table import Table        # only when suites run: --help stays fast
    from thermal_comp_common import plain_output   # rich and tqdm: only when suites run
    table = Table(title=f"bench {name}", show_lines=False)
    table.add_column("figure")
    table.add_column("value", justify="right")
    rows: list[tuple[str, Any]] = []
    _flatten("", figures, rows)
    for k, v in rows:
        table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    plain_output.console().print(table)


def main(argv: list[str] | None = None) -> int:
    """Run benchmarks and print and save every figure with the machine it ran on."""
    available = suites()
    ap = argparse.ArgumentParser(prog="thermal-comp bench", description=__doc__.split("\n\n")[0],
                                 epilog="suites: " + (", ".join(sorted(available)) or "(none installed)"))
    ap.add_argument("suites", nargs="*", metavar="SUITE", help="suites to run (default: all)")
    ap.add_argument("--json", metavar="OUT", help="write all figures (and the machine) to this JSON file")
    ap.add_argument("--quick", action="store_true", help="smaller problem sizes, for a smoke run")
    ap.add_argument("--out-dir", default=None, help="folder for plots and intermediate files of the suites")
    args, extra = ap.parse_known_args(argv)
    args.extra = extra
    names = args.suites or sorted(available)
    unknown = [n for n in names if n not in available]
    if unknown:
        print(f"thermal-comp bench: unknown suite(s) {unknown}; available: {sorted(available)}", file=sys.stderr)
        return 2
    if args.out_dir is None:
        args.out_dir = str(pathlib.Path("bench_out").resolve())
    pathlib.Path(args.out_dir).mkdir(parents=True, exist_ok=True)
    report: dict[str, Any] = {"machine": machine_info(), "suites": {}}
    print("machine: " + ", ".join(f"{k}={v}" for k, v in report["machine"].items()))
    failed = []
    for name in names:
        t0 = time.perf_counter()
        try:
            figures = available[name].load()(args)
        except Exception as exc:
            traceback.print_exc()
            failed.append(name)
            report["suites"][name] = {"error": f"{exc.__class__.__name__}: {exc}"}
            continue
        figures = dict(figures or {})
        figures.setdefault("suite_wall_s", round(time.perf_counter() - t0, 3))
        report["suites"][name] = figures
        print_figures(name, figures)
        if args.json:  # save after every suite: a later failure loses nothing
            _save(args.json, report)
    if args.json:
        _save(args.json, report)
        print(f"figures written to {args.json}")
    if failed:
        print(f"thermal-comp bench: suite(s) failed: {failed}", file=sys.stderr)
        return 1
    return 0


def _save(path: str, report: dict) -> None:
    p = pathlib.Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_suffix(p.suffix + ".tmp")
    tmp.write_text(json.dumps(report, indent=2, default=float))
    tmp.replace(p)
