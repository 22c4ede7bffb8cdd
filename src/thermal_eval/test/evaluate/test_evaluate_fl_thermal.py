"""FL_THERMAL through the generic evaluate path gives the FL_THERMAL benchmark's open-loop ARX figures."""
from __future__ import annotations

import pytest

from thermal_comp_common.metrics import mae
from thermal_eval.bench_evaluate import thinned
from thermal_eval.evaluation_run import evaluate
from thermal_eval.evaluation_spec import FL_THERMAL_SPEC, load_evaluation_data
from thermal_eval.fl_thermal_arx import arx_open_loop_channel
from thermal_eval.fl_thermal_data import Splits, load_fl_thermal
from thermal_eval.open_loop_models import MODELS


@pytest.mark.slow
def test_the_fl_thermal_spec_reproduces_the_benchmark_arx_on_the_quick_rows(shared_dir):
    csv = shared_dir / "data" / "fl_thermal" / "fl_thermal.csv"
    data = thinned(load_evaluation_data(csv, FL_THERMAL_SPEC), 4, FL_THERMAL_SPEC["split"])
    fl = load_fl_thermal(csv, every=4)
    splits = Splits.authors(len(fl))
    assert (data.split.n_train, data.split.test, data.split.validation) == (splits.n_train, splits.test,
                                                                           splits.validation)
    arx = next(m for m in MODELS if m.name == "arx_simulation")
    res = evaluate(data, models=[arx], adaptive=False, show_progress=False)
    for ch in ("ch1", "ch3"):
        ref = arx_open_loop_channel(fl, splits, ch)
        y = fl.displacement_um[ch]
        cell = res.figures["open_loop"]["arx_simulation"]["channels"][f"{ch}_um"]
        assert cell["params"]["inputs"] == [f"{s}_c" for s in ref.inputs]
        assert cell["mae_test_um"] == pytest.approx(round(mae(y[splits.test], ref.prediction[splits.test]), 3), abs=2e-3)
