"""The demo graph starts its observers (recorder, viewer, probe cycle) at a lower priority than
the control path sensors -> model -> bridge, and refuses a niceness it cannot apply."""
from __future__ import annotations

import io

import pytest

from thermal_comp.cell.config import parse_cell
from thermal_comp.demo.cell import MACHINES, DemoConfig, DemoError, build_cell
from thermal_comp.demo.graph import OBSERVER_NICE_ENV, OBSERVERS, _lower_observers, observer_niceness
from thermal_comp.cell.launcher import Launcher


def _config(tmp_path) -> DemoConfig:
    cfg = DemoConfig(out_dir=tmp_path, hours=1.0)
    cfg.scenario = MACHINES[cfg.machine]["scenario"]     # as bench graph sets it
    return cfg


def _niceness_by_node(tmp_path, nice: int) -> dict[str, int]:
    doc = build_cell(_config(tmp_path), 0, "opc.tcp://127.0.0.1:4840/x", live_view=True)
    _lower_observers(doc, nice)
    launcher = Launcher([parse_cell(doc, source="demo cell")], run_dir=tmp_path / "run", output=io.StringIO())
    return {mp.node.name: mp.nice for mp in launcher.processes}


def test_observers_run_below_the_control_path(tmp_path):
    nice = _niceness_by_node(tmp_path, 10)
    assert {n for n, v in nice.items() if v == 10} == set(OBSERVERS)
    assert all(nice[n] == 0 for n in ("machine_sim", "sensors", "model", "bridge"))


def test_niceness_zero_runs_every_process_alike(tmp_path):
    assert set(_niceness_by_node(tmp_path, 0).values()) == {0}


@pytest.mark.parametrize("value", ["-1", "20", "low"])
def test_a_bad_observer_niceness_is_one_error_naming_it(monkeypatch, value):
    monkeypatch.setenv(OBSERVER_NICE_ENV, value)
    with pytest.raises(DemoError, match=rf"{OBSERVER_NICE_ENV}='{value}'"):
        observer_niceness()


def test_observer_niceness_defaults_to_every_process_alike(monkeypatch):
    monkeypatch.delenv(OBSERVER_NICE_ENV, raising=False)
    assert observer_niceness() == 0
    monkeypatch.setenv(OBSERVER_NICE_ENV, "10")
    assert observer_niceness() == 10


def test_the_real_time_factor_reaches_machine_sim_and_a_bad_one_is_refused(tmp_path, capsys):
    from thermal_comp.demo.cli import _parser
    a = _parser().parse_args(["--real-time-factor", "600"])
    cfg = DemoConfig(out_dir=tmp_path, scenario="talc-178h-dry", real_time_factor=a.real_time_factor)
    sim = {n["name"]: n for n in build_cell(cfg, 0, None, False)["nodes"]}["machine_sim"]["parameters"]
    assert sim["real_time_factor"] == 600.0
    for bad in ("-1", "nan", "fast"):
        with pytest.raises(SystemExit):
            _parser().parse_args(["--real-time-factor", bad])
        assert f"{bad!r} is not a number >= 0" in capsys.readouterr().err
