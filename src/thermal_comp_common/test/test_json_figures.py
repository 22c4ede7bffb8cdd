import json
import math

import numpy as np

from thermal_comp_common.json_figures import finite_figures


def test_non_finite_figures_become_null_at_any_depth_and_the_rest_is_kept():
    report = {"a": math.nan, "b": [1.0, np.float64(np.inf), ("x", -math.inf)], "c": {"d": 2.5, "e": None}, "f": 3}
    out = finite_figures(report)
    assert out == {"a": None, "b": [1.0, None, ["x", None]], "c": {"d": 2.5, "e": None}, "f": 3}
    json.dumps(out, allow_nan=False)          # standard JSON
    assert math.isnan(report["a"])            # the input is not changed
