"""The ``conduction`` word: a heat path the twin lacks between two of its nodes (or a node
and a non-ambient boundary). Its candidates are exactly the unlinked pairs, an applied one
loads, and a path concealed in the mini_mill twin is named first with its conductance."""
from __future__ import annotations

import pathlib

import pytest

from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.diagnosis import diagnose
from thermal_twin.diagnose.effects import conduction, unlinked_pairs
from thermal_eval.diagnose.concealed import HiddenEffect, concealed_recording

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()


def test_the_candidates_are_the_unlinked_node_pairs_and_an_applied_one_loads():
    pairs = unlinked_pairs(SPEC)
    linked = {frozenset(d["between"]) for d in SPEC["links"].values()}
    assert pairs and all(frozenset(p) not in linked for p in pairs)
    # mini_mill: 4 nodes, 3 inner links, only the ambient boundary -> 6 - 3 = 3 pairs
    assert sorted(pairs) == [("head", "table"), ("spindle", "column"), ("spindle", "table")]
    c = conduction(SPEC, "spindle", "column")
    m = load_machine(c.apply(SPEC, [6.0]))
    assert any({ln.a, ln.b} == {"spindle", "column"} and ln.conductance == 6.0 for ln in m.links.values())
    assert c.implausible([250.0]) and not c.implausible([6.0])


def test_a_concealed_contact_is_named_first_with_its_conductance():
    rec, _ = concealed_recording(SPEC, [HiddenEffect("conduction", "spindle/column", None, (6.0,))],
                                 hours=48.0, step_s=300.0, seed=1)
    rep = diagnose(SPEC, rec).report
    first = rep["selected"][0]
    assert (first["effect"], first["target"]) == ("conduction", "spindle/column"), rep["selected"]
    assert first["params"]["G"]["value"] == pytest.approx(6.0, rel=0.15)
    assert len(rep["selected"]) == 1, rep["selected"]
