"""diagnose and calibrate give the same answer on every task engine.

A concealed-suite case (mini_mill, a heat source hidden in the table, 24 h at 300 s) is
diagnosed serially (one process), on a local pool of 2 processes and on a Dask LocalCluster
of 2: the reports (every hypothesis, parameter, score and statistic; timings aside) are equal
to the bit, and so is a calibrate-first diagnosis's calibration. Channel analyses, candidate
screening and fits, the unnamed fits and the Jacobian columns run as engine tasks and come
back in completion order, so this checks that results are put back in the tasks' order and
that no state of the parent process enters a task.
"""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

from thermal_comp_common.runtime.task_engine import EngineSpec
from thermal_eval.diagnose.concealed import HiddenEffect as H, concealed_recording
from thermal_twin.calibrate.fit import calibrate
from thermal_twin.machine.schema import load_machine
from thermal_twin.diagnose.diagnosis import diagnose

SPEC = load_machine(pathlib.Path(__file__).parent / "mini_mill.yaml").to_dict()
TIMINGS = ("wall_s", "simulated_h_per_s")


def _timeless(x):
    """The report without its wall-time figures."""
    if isinstance(x, dict):
        return {k: _timeless(v) for k, v in x.items() if k not in TIMINGS}
    if isinstance(x, list):
        return [_timeless(v) for v in x]
    return x


@pytest.fixture(scope="module")
def recording():
    rec, _ = concealed_recording(SPEC, (H("heat_source", "table", "spindle_rpm", (40.0, 1.0)),),
                                 hours=24.0, step_s=300.0, seed=1)
    return rec


@pytest.fixture(scope="module")
def serial(recording):
    return diagnose(SPEC, recording, engine=EngineSpec("local", workers=1))


def _assert_same(d, ref):
    assert _timeless(d.report) == _timeless(ref.report)
    assert d.augmented_spec == ref.augmented_spec
    for c in ref.series.after:
        np.testing.assert_array_equal(d.series.after[c], ref.series.after[c])


def test_the_serial_diagnosis_finds_the_hidden_source(serial):
    rep = serial.report
    assert rep["answer"] == "heat_source" and rep["selected"][0]["target"] == "table"
    assert len(rep["hypotheses"]) >= 3 and rep["simulations"] > 0


def test_a_local_pool_of_two_gives_the_serial_report(recording, serial):
    _assert_same(diagnose(SPEC, recording, engine=EngineSpec("local", workers=2)), serial)


@pytest.mark.slow
def test_a_dask_local_cluster_of_two_gives_the_serial_report(recording, serial):
    _assert_same(diagnose(SPEC, recording, engine=EngineSpec("dask", workers=2)), serial)


def test_calibrate_first_and_calibrate_give_the_same_answer_on_two_processes(recording):
    one = diagnose(SPEC, recording, calibrate=True, unnamed=False, max_effects=1,
                   engine=EngineSpec("local", workers=1))
    two = diagnose(SPEC, recording, calibrate=True, unnamed=False, max_effects=1,
                   engine=EngineSpec("local", workers=2))
    _assert_same(two, one)
    assert one.report["calibration"]["twin_evaluations"] > 0
    a = calibrate(SPEC, recording, max_nfev=6)
    b = calibrate(SPEC, recording, max_nfev=6, engine=EngineSpec("local", workers=2))
    assert [e.as_dict() for e in a.estimates] == [e.as_dict() for e in b.estimates]
    assert (a.n_evals, a.cost_after, a.simulated_h) == (b.n_evals, b.cost_after, b.simulated_h)


@pytest.mark.parametrize("flags, named", [(["--jobs", "0"], "--jobs: 0"),
                                          (["--address", "tcp://host:8786"], "address: 'tcp://host:8786'"),
                                          (["--engine", "dask", "--address", "host:8786"], "address: 'host:8786'")])
def test_bad_engine_options_give_one_line_naming_the_option(flags, named, tmp_path, capsys):
    from thermal_twin.calibrate.cli import main as calibrate_main
    from thermal_twin.diagnose.cli import main as diagnose_main
    common = ["--twin", "spindle-stand", "--recording", str(tmp_path / "rec.csv")]
    assert diagnose_main(common + ["--out", str(tmp_path / "d"), *flags]) == 1
    assert calibrate_main(common + ["--out", str(tmp_path / "c"), *flags]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and all(named in line for line in err), err
    assert not (tmp_path / "d").exists() and not (tmp_path / "c").exists()
