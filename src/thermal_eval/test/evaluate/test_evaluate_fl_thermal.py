"""`bench fl-thermal` is one dataset configuration of the generic evaluate path: the FL_THERMAL
spec read from the CSV gives the benchmark's data, and the benchmark's open-loop ARX figures are
the generic ``arx_simulation`` row's."""
from __future__ import annotations

import numpy as np
import pytest

from thermal_eval.bench.evaluate import thinned
from thermal_eval.evaluate.run import evaluate
from thermal_eval.evaluate.spec import FL_THERMAL_SPEC, load_evaluation_data
from thermal_eval.fl_thermal.benchmark import run_open_loop
from thermal_eval.fl_thermal.data import CHANNELS, Splits, as_evaluation_data, load_fl_thermal
from thermal_eval.evaluate.open_loop_models import MODELS


@pytest.mark.slow
def test_the_fl_thermal_spec_reproduces_the_benchmark_arx_on_the_quick_rows(shared_dir):
    csv = shared_dir / "data" / "fl_thermal" / "fl_thermal.csv"
    data = thinned(load_evaluation_data(csv, FL_THERMAL_SPEC), 4, FL_THERMAL_SPEC["split"])
    fl = load_fl_thermal(csv, every=4)
    splits = Splits.authors(len(fl))
    bench = as_evaluation_data(fl, splits)
    assert (data.split.n_train, data.split.test, data.split.validation) == (splits.n_train, splits.test,
                                                                           splits.validation)
    assert bench.split == data.split
    np.testing.assert_allclose(bench.temperatures, data.temperatures)
    np.testing.assert_allclose(bench.inputs, data.inputs)
    for ch in CHANNELS:
        np.testing.assert_allclose(bench.displacement_um[ch], data.displacement_um[f"{ch}_um"])
    arx = next(m for m in MODELS if m.name == "arx_simulation")
    res = evaluate(data, models=[arx], adaptive=False, show_progress=False)
    figures, predictions, baselines = run_open_loop(fl, splits, tau_grid=[()], alpha_grid=[1.0], show_progress=False)
    assert set(baselines) == {"train_mean", "hold_last_training", "static_ls", "lowpass_ridge"}
    for ch in CHANNELS:
        cell = res.figures["open_loop"]["arx_simulation"]["channels"][f"{ch}_um"]
        ours = figures["arx_simulation"][ch]
        assert ours["inputs"] == [s.removesuffix("_c") for s in cell["params"]["inputs"]]
        assert (ours["mae_um"], ours["mae_validation_um"]) == (cell["mae_test_um"], cell["mae_validation_um"])
        assert np.all(np.isfinite(predictions["arx_simulation"][ch][splits.n_train:]))
