"""docs/models_without_ros.md: its python block runs as written (so the example cannot rot)."""
import contextlib
import io
import json
import re

from talc_model import AdaptiveModel, TalcModel, load_model


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```$", text, flags=re.S | re.M)


def test_the_documented_example_runs_and_adapts_talc_on_the_synthetic_plant(request, tmp_path, monkeypatch):
    doc = (request.config.rootpath / "docs" / "models_without_ros.md").read_text()
    blocks = _python_blocks(doc)
    assert len(blocks) == 1 and len(blocks[0].splitlines()) <= 15
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(blocks[0], "models_without_ros.md", "exec"), ns)
    model = ns["model"]
    assert isinstance(model, TalcModel) and isinstance(model, AdaptiveModel)
    status = model.status(ns["t"])
    assert status.phase == "compensation" and status.probing_cycles > 10 and status.q_prod_pct > 90.0
    assert "phase='compensation'" in out.getvalue()
    restored = load_model(tmp_path / "talc_state.json")
    assert restored.to_state() == json.loads(json.dumps(model.to_state()))
