"""The command line starts light: ``thermal-comp --help`` reads the summaries without importing a
subcommand, and each subcommand's module builds its parser without the heavy libraries (the
work is imported once the arguments are parsed). Checked on what gets imported, never on time
(``thermal-comp bench cli`` measures that).
"""
from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import entry_points

import pytest

from thermal_comp.cli import GROUP

COMMANDS = sorted(entry_points(group=GROUP), key=lambda ep: ep.name)
#: libraries that take a large part of a second to import; no command's --help needs them
HEAVY = ("scipy", "sklearn", "rclpy", "matplotlib", "pandas", "rerun", "asyncua")
#: a command whose help does need one of them, and why
HEAVY_FOR_HELP = {"record": {"rclpy"}}   # its help lists the recorder node's topic table (QoS: rclpy)

_PROBE = r"""
import contextlib, io, json, sys
heavy = set(sys.argv[1].split(","))
def loaded():
    return sorted({m.split(".")[0] for m in sys.modules} & heavy)
import importlib
module = importlib.import_module(sys.argv[2])
after_import = loaded()
from thermal_comp.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    try:
        code = main(sys.argv[3:])
    except SystemExit as exc:
        code = exc.code
print(json.dumps({"after_import": after_import, "after_help": loaded(), "code": code,
                  "modules": sorted(sys.modules), "out": out.getvalue()}))
"""


def _probe(module: str, argv: list[str]) -> dict:
    """Import ``module`` and run ``thermal-comp ARGV`` in a fresh interpreter: what got imported."""
    p = subprocess.run([sys.executable, "-c", _PROBE, ",".join(HEAVY), module, *argv],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(p.stdout)


def test_top_level_help_lists_every_command_without_importing_one():
    r = _probe("thermal_comp.cli", ["--help"])
    assert r["code"] == 0 and r["out"].startswith("usage: thermal-comp COMMAND")
    for ep in COMMANDS:
        line = next(ln for ln in r["out"].splitlines() if ln.split()[:1] == [ep.name])
        assert len(line.split()) > 1 and "(unavailable" not in line, line
    imported = {ep.value.split(":")[0] for ep in COMMANDS} & set(r["modules"])
    assert imported == set(), f"--help imported subcommand modules: {sorted(imported)}"
    assert r["after_help"] == []


def test_the_summary_is_the_first_docstring_line_of_the_command_module():
    from thermal_comp import cli
    ep = next(ep for ep in COMMANDS if ep.name == "sim")
    import thermal_twin.sim.cli as sim_cli
    assert cli._summary(ep) == sim_cli.__doc__.strip().splitlines()[0]


def test_unknown_command_exits_2_with_the_usage(capsys):
    from thermal_comp import cli
    assert cli.main(["no-such-command"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'no-such-command'" in err and "usage: thermal-comp COMMAND" in err


@pytest.mark.parametrize("ep", COMMANDS, ids=lambda ep: ep.name)
def test_command_help_exits_0_without_heavy_imports(ep):
    r = _probe(ep.value.split(":")[0], [ep.name, "--help"])
    assert r["code"] == 0
    assert r["out"].startswith(f"usage: thermal-comp {ep.name}"), r["out"][:200]
    allowed = HEAVY_FOR_HELP.get(ep.name, set())
    assert set(r["after_import"]) <= allowed, f"importing {ep.value} loads {r['after_import']}"
    assert set(r["after_help"]) <= allowed, f"{ep.name} --help loads {r['after_help']}"


def test_the_exceptions_are_real_commands():
    assert set(HEAVY_FOR_HELP) <= {ep.name for ep in COMMANDS}
