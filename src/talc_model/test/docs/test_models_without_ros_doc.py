"""docs/models_without_ros.md: its python blocks run as written (so the examples cannot rot)."""
import contextlib
import io
import json
import re

import numpy as np

from talc_model import AdaptiveModel, ProbeRefitModel, TalcModel, load_model, model_from_state


def _python_blocks(request) -> list[str]:
    doc = (request.config.rootpath / "docs" / "models_without_ros.md").read_text()
    return re.findall(r"^```python\n(.*?)^```$", doc, flags=re.S | re.M)


def _run(block: str, name: str) -> tuple[dict, str]:
    ns: dict = {}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(block, name, "exec"), ns)
    return ns, out.getvalue()


def test_the_documented_example_runs_and_adapts_talc_on_the_synthetic_plant(request, tmp_path, monkeypatch):
    blocks = _python_blocks(request)
    assert len(blocks) == 2 and all(len(b.splitlines()) <= 15 for b in blocks)
    monkeypatch.chdir(tmp_path)
    ns, out = _run(blocks[0], "models_without_ros.md")
    model = ns["model"]
    assert isinstance(model, TalcModel) and isinstance(model, AdaptiveModel)
    status = model.status(ns["t"])
    assert status.phase == "compensation" and status.probing_cycles > 10 and status.q_prod_pct > 90.0
    assert "phase='compensation'" in out
    restored = load_model(tmp_path / "talc_state.json")
    assert restored.to_state() == json.loads(json.dumps(model.to_state()))


def test_the_documented_refit_compensator_runs_and_compensates_most_of_the_error(request):
    ns, out = _run(_python_blocks(request)[1], "models_without_ros.md (refit)")
    refit, plant, left = ns["refit"], ns["plant"], ns["left"]
    assert isinstance(refit, ProbeRefitModel) and "phase='compensation'" in out
    calibration = refit.config["calibration_probes"]
    assert len(left) > calibration + 20
    after = plant.time_s >= plant.time_s[0] + calibration * refit.config["calibration_interval_s"]
    for c in refit.component_names:      # the probes after calibration see a small part of the error
        assert np.mean([abs(v[c]) for v in left[calibration:]]) < 0.25 * np.mean(np.abs(plant.errors[c][after]))
    state = json.loads(json.dumps(refit.to_state()))
    assert model_from_state(state).predict(ns["t"]) == refit.predict(ns["t"])
