"""The launcher starts a node at the niceness its environment asks for (THERMAL_COMP_NICE), and
refuses a value that is not a niceness 0-19 with one error naming the node and the value."""
from __future__ import annotations

import io
import os
import re

import pytest

from thermal_comp.cell.config import CellConfigError, parse_cell
from thermal_comp.cell.launcher import NICE_ENV, Launcher


def _cell(tmp_path, env: dict[str, str]):
    (tmp_path / "print_nice.py").write_text(
        "import os, pathlib\nprint('niceness', os.nice(0), flush=True)\n"
        "group = pathlib.Path('/proc/self/autogroup')\n"
        "print('autogroup', group.read_text().split()[-1] if group.exists() else 'none', flush=True)\n")
    node_env = {"PYTHONPATH": str(tmp_path), **env}
    doc = {"cell": "nicecell", "nodes": [{"name": "observer", "module": "print_nice", "env": node_env,
                                          "restart": {"enabled": False}}]}
    return parse_cell(doc, source="test cell", resolve=False)


@pytest.mark.parametrize("nice", [0, 7])
def test_a_node_starts_at_the_niceness_of_its_environment(tmp_path, nice):
    out = io.StringIO()
    env = {NICE_ENV: str(nice)} if nice else {}
    launcher = Launcher([_cell(tmp_path, env)], run_dir=tmp_path / "run", output=out, grace_s=5.0)
    assert launcher.run(poll_s=0.05) == 0
    text = out.getvalue()
    own = os.nice(0)     # the child's niceness is the launcher's plus the node's
    assert re.search(rf"\[nicecell/observer\] niceness {min(own + nice, 19)}$", text, re.M), text
    assert (f"at nice {nice}" in text) == bool(nice), text
    # autogroup scheduling: the node's session is a group of its own, lowered as well
    group = re.search(r"\[nicecell/observer\] autogroup (\S+)$", text, re.M).group(1)
    assert group in ("none", str(nice)), text


@pytest.mark.parametrize("value", ["-5", "20", "high"])
def test_a_bad_niceness_is_one_error_naming_node_and_value(tmp_path, value):
    with pytest.raises(CellConfigError, match=rf"nicecell/observer: env {NICE_ENV}='{value}'"):
        Launcher([_cell(tmp_path, {NICE_ENV: value})], run_dir=tmp_path / "run", output=io.StringIO())
