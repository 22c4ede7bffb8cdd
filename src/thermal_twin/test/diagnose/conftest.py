"""Collects the concealed-effect outcomes and prints the confusion table of the suite."""
from __future__ import annotations

import collections

import pytest

OUTCOMES: list[tuple[str, str]] = []   # (true label, label ranked first / selected)


def confusion_table(outcomes: list[tuple[str, str]]) -> str:
    """Rows: the concealed effect; columns (by number): what the finder ranked first."""
    labels = sorted({t for t, _ in outcomes} | {p for _, p in outcomes})
    counts = collections.Counter(outcomes)
    code = {l: f"[{i}]" for i, l in enumerate(labels, 1)}
    w = max(len(f"{code[l]} {l}") for l in labels) + 1
    lines = ["true \\ found".ljust(w) + " ".join(code[l].rjust(5) for l in labels)]
    for t in labels:
        if any(tt == t for tt, _ in outcomes):
            lines.append(f"{code[t]} {t}".ljust(w) + " ".join(str(counts[(t, p)] or ".").rjust(5) for p in labels))
    right = sum(c for (t, p), c in counts.items() if t == p)
    lines.append(f"{right}/{len(outcomes)} cases ranked the true effect first")
    return "\n".join(lines)


def pytest_terminal_summary(terminalreporter):
    if OUTCOMES:
        terminalreporter.section("mismatch finder: confusion table over the concealed-effect suite")
        terminalreporter.write_line(confusion_table(OUTCOMES))


@pytest.fixture(scope="session")
def confusion_outcomes() -> list[tuple[str, str]]:
    """Tests append (true label, found label); printed at the end of the session."""
    return OUTCOMES
