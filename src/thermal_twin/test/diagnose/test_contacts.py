"""Declared ``contacts`` (which places physically touch) in a machine YAML: validated with a clear
error, kept through a dump, and used by the finder's words. With contacts, ``conduction`` never
proposes a path between parts that do not touch, and ``elastic_gain`` can add back a
thermo-elastic term a channel lacks on a node touching its nodes; without, both are unchanged."""
from __future__ import annotations

import copy
import pathlib

import numpy as np
import pytest

from thermal_twin.machine.schema import MachineSpecError, dump_machine, load_machine
from thermal_twin.diagnose.diagnosis import diagnose
from thermal_twin.diagnose.effects import DriverInfo, candidates, elastic_nodes, unlinked_pairs
from thermal_eval.diagnose.concealed import HiddenEffect, concealed_recording

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()
#: mini_mill's structure: spindle in the head, head on the column, table on the column's bed,
#: and (declared here, not linked) a spindle-column contact
CONTACTS = [["spindle", "head"], ["head", "column"], ["column", "table"], ["spindle", "column"]]


def _with_contacts(spec: dict, contacts=CONTACTS) -> dict:
    s = copy.deepcopy(spec)
    s["contacts"] = copy.deepcopy(contacts)
    return load_machine(s).to_dict()


def _keys(spec: dict) -> set[str]:
    drivers = {"spindle_rpm": DriverInfo("spindle_rpm", 12000.0, "speed")}
    chans = [f"{s}_c" for s in spec["sensors"]] + list(spec["errors"])
    return {c.key for c in candidates(spec, drivers, chans)}


def test_an_unknown_place_in_contacts_is_one_error_naming_it():
    with pytest.raises(MachineSpecError, match=r"contacts\[1\]\[1\]: 'colum' is not a node or boundary"):
        _with_contacts(SPEC, [["spindle", "head"], ["head", "colum"]])
    with pytest.raises(MachineSpecError, match=r"contacts\[0\].*itself"):
        _with_contacts(SPEC, [["head", "head"]])
    with pytest.raises(MachineSpecError, match=r"contacts\[1\].*declared twice"):
        _with_contacts(SPEC, [["head", "column"], ["column", "head"]])
    with pytest.raises(MachineSpecError, match=r"contacts: .* must be a list"):
        _with_contacts(SPEC, {"head": "column"})


def test_contacts_survive_a_dump_and_load():
    s = _with_contacts(SPEC)
    assert load_machine(dump_machine(load_machine(s))).to_dict()["contacts"] == CONTACTS


def test_undeclared_every_pair_declared_only_touching_pairs_are_proposed():
    assert sorted(unlinked_pairs(SPEC)) == [("head", "table"), ("spindle", "column"), ("spindle", "table")]
    s = _with_contacts(SPEC)
    assert unlinked_pairs(s) == [("spindle", "column")]
    keys = _keys(s)
    assert "conduction:spindle/column:-" in keys
    # the table touches neither the spindle nor the head: no path to them is ever proposed
    assert not {"conduction:spindle/table:-", "conduction:head/table:-"} & keys
    assert {"conduction:spindle/table:-", "conduction:head/table:-"} <= _keys(SPEC)


def test_elastic_terms_undeclared_existing_only_declared_also_touching_nodes():
    assert elastic_nodes(SPEC, "E_X0C") == ["table", "column"]
    s = _with_contacts(SPEC)
    # E_X0C's nodes table and column touch head and spindle (column-head, column-spindle)
    assert elastic_nodes(s, "E_X0C") == ["table", "column", "spindle", "head"]
    del s["errors"]["E_Z0T"]["terms"]["head"]
    assert "elastic_gain:E_Z0T/head:-" in _keys(s)
    assert "elastic_gain:E_Z0T/head:-" not in _keys(
        {**copy.deepcopy(s), "contacts": []})


def test_a_removed_thermo_elastic_term_is_added_back_first():
    """The head term of E_Z0T (1.5 um/K) is removed from the twin; the recording comes from
    the full twin. The finder names the term back, from zero, within 15 %."""
    full = _with_contacts(SPEC)
    ablated = copy.deepcopy(full)
    ref = ablated["errors"]["E_Z0T"]["terms"].pop("head")
    rec, _ = concealed_recording(ablated, [HiddenEffect("elastic_gain", "E_Z0T/head", None, (ref,))],
                                 hours=48.0, step_s=300.0, seed=3)
    rep = diagnose(ablated, rec).report
    first = rep["selected"][0]
    assert (first["effect"], first["target"]) == ("elastic_gain", "E_Z0T/head"), rep["selected"]
    assert first["params"]["d_gain"]["value"] == pytest.approx(ref, rel=0.15)
    assert np.isfinite(first["holdout_improvement_pct"]) and first["holdout_improvement_pct"] > 50
