"""One ``--jobs`` for every command: one definition (engine_options.add_jobs_argument) and one
default (all cores but one, at least 1)."""
from __future__ import annotations

import pathlib
import re

import pytest

from thermal_comp_common.runtime import engine_options
from thermal_eval.bench.evaluate import parser as bench_evaluate_parser
from thermal_eval.evaluate.cli import parser as evaluate_parser
from thermal_eval.sweep.cli import parser as sweep_parser
from thermal_twin.calibrate.cli import build_parser as calibrate_parser
from thermal_twin.diagnose.cli import build_parser as diagnose_parser

SRC = pathlib.Path(__file__).resolve().parents[3]
#: every command whose work runs on the task engine, with the fewest arguments it parses
COMMANDS = {
    "evaluate": (evaluate_parser, ["rec.csv", "--out", "o"]),
    "sweep": (sweep_parser, ["rec.csv", "--out", "o"]),
    "calibrate": (calibrate_parser, ["--twin", "spindle-stand", "--recording", "r.csv", "--out", "o"]),
    "diagnose": (diagnose_parser, ["--twin", "spindle-stand", "--recording", "r.csv", "--out", "o"]),
    "bench evaluate": (bench_evaluate_parser, []),
}


@pytest.mark.parametrize("cores, jobs", [(1, 1), (2, 1), (8, 7)])
def test_the_default_is_all_cores_but_one_and_at_least_one(monkeypatch, cores, jobs):
    monkeypatch.setattr(engine_options, "default_workers", lambda: cores)
    assert engine_options.default_jobs() == jobs


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_every_command_parser_takes_the_shared_default(monkeypatch, name):
    make, argv = COMMANDS[name]
    monkeypatch.setattr(engine_options, "default_workers", lambda: 6)      # not this machine's count
    args = make().parse_args(argv)
    assert args.jobs == 5
    assert make().parse_args(argv + ["--jobs", "3"]).jobs == 3
    if "--workers" in make().format_help():
        assert make().parse_args(argv + ["--workers", "2"]).jobs == 2


def test_no_other_jobs_option_is_defined_in_the_sources():
    defined = set()
    for path in SRC.glob("*/*/**/*.py"):
        rel = path.relative_to(SRC).as_posix()
        if "/test" in rel or rel.endswith("runtime/engine_options.py"):
            continue
        if re.search(r"add_argument\(\s*[\"']--jobs[\"']", path.read_text(encoding="utf-8")):
            defined.add(rel)
    assert defined == set()
