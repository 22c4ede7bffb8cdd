"""`thermal-comp probe`'s progress: the action's result may arrive before its last feedback (two
topics); a cycle that succeeded ends its progress at every point, one that failed where it stopped."""
from __future__ import annotations

import argparse
import re
from types import SimpleNamespace

import pytest

from thermal_comp.api.results import Errors, ProbeResult
from thermal_comp.cell import inspect_graph


class _OvertakingCell:
    """A cell whose probing cycle sends feedback up to 23 of 25 points, then its result."""

    def __init__(self, success: bool):
        self.success = success
        self.graph = SimpleNamespace(domain_id=0)

    def probe(self, on_feedback, **_kw) -> ProbeResult:
        for done in (3, 13, 23):
            on_feedback(SimpleNamespace(points_total=25, points_done=done))
        errors = Errors(0.0, "machine_base", "probe", {"E_X0C": 1.5}, {"E_X0C": "um"}, {"E_X0C": 0.5})
        return ProbeResult(self.success, "measured" if self.success else "probe collision", errors, 30.0, 0.2, 0.1)

    def close(self) -> None:
        pass


@pytest.mark.parametrize("success, line", [(True, r"^probing: 25/25 points \(100 %\), done"),
                                           (False, r"^probing: 23/25 points \(92 %\), stopped")])
def test_the_last_progress_line_follows_the_result_not_the_last_feedback(monkeypatch, capsys, success, line):
    monkeypatch.setattr(inspect_graph.Cell, "attach", staticmethod(lambda *_a: _OvertakingCell(success)))
    args = argparse.Namespace(namespace="/c", domain_id=None, guide_bush=False, set_reference=False, points=0,
                              timeout=60.0, wait=1.0, deadline=60.0, busy_retry=0.0)
    assert inspect_graph.probe(args, []) == (0 if success else 1)
    assert re.search(line, capsys.readouterr().err, flags=re.M)
