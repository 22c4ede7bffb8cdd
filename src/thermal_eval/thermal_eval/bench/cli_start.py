"""Benchmark ``thermal-comp bench cli``: start-up time of the command line.

Runs ``thermal-comp --help`` and ``thermal-comp SUB --help`` of every installed subcommand
(entry-point group ``thermal_comp.commands``) in fresh processes, a few times each, and reports
the median wall time and the median CPU time (user + system) of each process. ``--quick``: two
runs each instead of five. Figures: ``<command>.wall_s``, ``<command>.cpu_s``, ``<command>.exit_code``
(``help`` is the top-level ``thermal-comp --help``), ``max_wall_s``, ``slowest``, ``runs``.
"""
from __future__ import annotations

import argparse
import pathlib
import resource
import statistics
import subprocess
import sys
import time
from importlib.metadata import entry_points

COMMANDS_GROUP = "thermal_comp.commands"


def thermal_comp_command() -> list[str]:
    """The installed console script beside this interpreter, else the dispatcher module."""
    script = pathlib.Path(sys.executable).with_name("thermal-comp")
    return [str(script)] if script.is_file() else [sys.executable, "-m", "thermal_comp.cli"]


def time_process(argv: list[str]) -> tuple[float, float, int]:
    """(wall s, CPU s of the process, exit code) of one run of ``argv``, its output discarded."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    code = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, code


def measure(runs: int) -> dict[str, dict]:
    """Median wall and CPU seconds of ``--help`` and of each ``SUB --help`` over ``runs`` runs."""
    base = thermal_comp_command()
    cases = {"help": ["--help"]}
    cases.update({name: [name, "--help"] for name in sorted({ep.name for ep in entry_points(group=COMMANDS_GROUP)})})
    out = {}
    for name, args in cases.items():
        samples = [time_process(base + args) for _ in range(runs)]
        out[name] = {"wall_s": round(statistics.median(s[0] for s in samples), 3),
                     "cpu_s": round(statistics.median(s[1] for s in samples), 3),
                     "exit_code": max((s[2] for s in samples), key=abs)}
    return out


def print_table(rows: dict[str, dict], runs: int) -> None:
    print(f"thermal-comp start-up, median of {runs} fresh processes")
    print(f"  {'command':34s} {'wall s':>7s} {'CPU s':>7s} {'exit':>5s}")
    for name, r in rows.items():
        label = "thermal-comp --help" if name == "help" else f"thermal-comp {name} --help"
        print(f"  {label:34s} {r['wall_s']:7.3f} {r['cpu_s']:7.3f} {r['exit_code']:5d}")


def run(args: argparse.Namespace | None = None) -> dict:
    runs = 2 if getattr(args, "quick", False) else 5
    rows = measure(runs)
    print_table(rows, runs)
    slowest = max(rows, key=lambda n: rows[n]["wall_s"])
    return {**rows, "max_wall_s": rows[slowest]["wall_s"], "slowest": slowest, "runs": runs}
