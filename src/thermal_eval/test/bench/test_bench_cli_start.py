"""``thermal-comp bench cli``: one fresh process per command line, the median of the runs, the
exit code kept; figures are only reported, never asserted against a time."""
from __future__ import annotations

import argparse
import sys
from types import SimpleNamespace

from thermal_eval.bench import cli_start


def test_time_process_reports_the_exit_code_of_a_fresh_process():
    wall, cpu, code = cli_start.time_process([sys.executable, "-c", "raise SystemExit(3)"])
    assert code == 3 and wall > 0.0 and cpu >= 0.0


def test_run_times_top_level_help_and_each_subcommand(monkeypatch, capsys):
    calls = []

    def fake_time(argv):
        calls.append(argv[1:])
        return {("--help",): (0.3, 0.1, 0), ("a", "--help"): (0.5, 0.2, 0)}.get(tuple(argv[1:]), (0.9, 0.4, 2))
    monkeypatch.setattr(cli_start, "time_process", fake_time)
    monkeypatch.setattr(cli_start, "thermal_comp_command", lambda: ["thermal-comp"])
    monkeypatch.setattr(cli_start, "entry_points",
                        lambda group: [SimpleNamespace(name="b"), SimpleNamespace(name="a")])
    figures = cli_start.run(argparse.Namespace(quick=True))
    assert calls == [["--help"]] * 2 + [["a", "--help"]] * 2 + [["b", "--help"]] * 2
    assert figures["help"] == {"wall_s": 0.3, "cpu_s": 0.1, "exit_code": 0}
    assert figures["b"]["exit_code"] == 2
    assert figures["slowest"] == "b" and figures["max_wall_s"] == 0.9 and figures["runs"] == 2
    out = capsys.readouterr().out
    assert "thermal-comp a --help" in out and "thermal-comp --help" in out


def test_the_suite_is_registered():
    from importlib.metadata import entry_points
    (ep,) = [ep for ep in entry_points(group="thermal_comp.bench") if ep.name == "cli"]
    assert ep.load() is cli_start.run
