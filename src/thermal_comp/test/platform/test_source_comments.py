"""Source says what and why, not when: no file of a package (code, tests, shipped configs and
interface files) names the issue or work session that brought a change. That history belongs
in docs/ and in commit messages."""
from __future__ import annotations

import pathlib
import re

import pytest

SRC = pathlib.Path(__file__).resolve().parents[3]
SUFFIXES = {".py", ".yaml", ".yml", ".xml", ".msg", ".srv", ".action", ".cfg", ".toml"}
HISTORY = re.compile(r"\b[Ii]ssues? #?\d+|\b[Ss]essions? #?\d+|\b[Ss]ession-\d|\bsince (?:session|issue)\b"
                     r"|\([Ii]ssue\b|\bstop \d+\b")


def source_files() -> list[pathlib.Path]:
    """Every text file of every package under src/<pkg>/ except its documentation."""
    return sorted(p for p in SRC.glob("*/**/*") if p.is_file() and p.suffix in SUFFIXES
                  and "__pycache__" not in p.parts and "docs" not in p.relative_to(SRC).parts)


def history_lines(path: pathlib.Path) -> list[str]:
    text = path.read_text(errors="replace")
    return [f"{path.relative_to(SRC)}:{i}: {line.strip()}"
            for i, line in enumerate(text.splitlines(), 1) if HISTORY.search(line)]


# {s}/{i}/{n} stand for "session"/"issue"/a number, so that this file does not match its own search
@pytest.mark.parametrize("line, found", [
    ("# since {s} the filter is on", True), ('"""{I} {n}: the CNC held X."""', True),
    ("({i} {n} part 1)", True), ("docs/talc.md, {s}s {n} and 8.", True), ("the {s}-{n}..8 inputs", True),
    ("work stop {n}", True), ("a {s} on the emulated CNC", False), ("the pytest {s}", False),
    ("stop_s = {n}", False), ("{i}_{n}", False),
])
def test_the_pattern_finds_history_and_leaves_other_words(line, found):
    text = line.format(s="session", i="issue", I="Issue", n=23)
    assert bool(HISTORY.search(text)) is found


def test_the_search_covers_every_package():
    packages = {p.relative_to(SRC).parts[0] for p in source_files()}
    assert {"talc_model", "thermal_eval", "thermal_twin", "cnc_bridge", "thermal_comp_common"} <= packages
    assert pathlib.Path(__file__).resolve() in source_files()


def test_no_source_line_names_an_issue_or_a_session():
    found = [line for p in source_files() for line in history_lines(p)]
    assert not found, "history in source (say what and why; history goes to docs/):\n" + "\n".join(found)
