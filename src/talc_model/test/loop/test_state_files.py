"""Where the model state lives, its saved time, and a refused state kept aside."""
from __future__ import annotations

import pathlib
import stat

from talc_model.adaptive_model import make_model
from talc_model.model_persistence import save_model
from talc_model.state_files import move_aside, resolve_state_path, saved_time_s, state_dir


def test_a_relative_state_path_lives_under_the_users_state_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "xdg"))
    assert resolve_state_path("") is None
    p = resolve_state_path("nmv5000/model.json")
    assert p == tmp_path / "xdg" / "thermal-comp" / "nmv5000" / "model.json"
    assert stat.S_IMODE(p.parent.stat().st_mode) == 0o700
    absolute = tmp_path / "abs" / "m.json"
    assert resolve_state_path(str(absolute)) == absolute and absolute.parent.is_dir()


def test_without_xdg_state_home_the_default_is_under_home(tmp_path, monkeypatch):
    monkeypatch.delenv("XDG_STATE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))
    assert state_dir() == tmp_path / ".local" / "state" / "thermal-comp"
    monkeypatch.setenv("XDG_STATE_HOME", "relative/not/allowed")     # the spec: ignore a relative one
    assert state_dir() == tmp_path / ".local" / "state" / "thermal-comp"
    assert resolve_state_path("~/x/m.json") == tmp_path / "x" / "m.json"


def test_saved_time_comes_from_the_saved_envelope(tmp_path):
    model = make_model("talc", {"component_names": ["E_X0C"], "input_names": ["a"]})
    path = tmp_path / "m.json"
    save_model(path, model, extra={"model_time_s": 37920.0})
    assert saved_time_s(path, model) == 37920.0
    save_model(path, model)                        # no saved time: the model's own last input time
    assert saved_time_s(path, model) is None       # (never updated: -inf, unknown)


def test_a_refused_state_is_moved_aside_never_deleted(tmp_path):
    path = tmp_path / "model.json"
    path.write_text("one")
    first = move_aside(path, 37920.0)
    assert first.name == "model.refused-t37920.json" and first.read_text() == "one" and not path.exists()
    path.write_text("two")
    second = move_aside(path, 37920.0)
    assert second.name == "model.refused-t37920-1.json" and second.read_text() == "two"
    assert {p.name for p in pathlib.Path(tmp_path).iterdir()} == {first.name, second.name}
