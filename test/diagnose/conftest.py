"""Collects the concealed-effect outcomes and prints the confusion table of the suite."""
from __future__ import annotations

import collections

OUTCOMES: list[tuple[str, str]] = []   # (true label, label ranked first / selected)


def confusion_table(outcomes: list[tuple[str, str]]) -> str:
    labels = sorted({t for t, _ in outcomes} | {p for _, p in outcomes})
    counts = collections.Counter(outcomes)
    w = max(len(x) for x in labels + ["true \\ found"]) + 1
    lines = ["true \\ found".ljust(w) + " ".join(l[:6].rjust(6) for l in labels)]
    for t in labels:
        if not any(tt == t for tt, _ in outcomes):
            continue
        lines.append(t.ljust(w) + " ".join(str(counts[(t, p)] or ".").rjust(6) for p in labels))
    right = sum(c for (t, p), c in counts.items() if t == p)
    lines.append(f"{right}/{len(outcomes)} cases ranked the true effect first")
    return "\n".join(lines)


def pytest_terminal_summary(terminalreporter):
    if OUTCOMES:
        terminalreporter.section("mismatch finder: confusion table over the concealed-effect suite")
        terminalreporter.write_line(confusion_table(OUTCOMES))


import pytest  # noqa: E402


@pytest.fixture(scope="session")
def confusion_outcomes() -> list[tuple[str, str]]:
    """Tests append (true label, found label); printed at the end of the session."""
    return OUTCOMES
