"""Where a node's model state file lives, the model time it was saved at, and how a refused
one is kept: a state that does not fit the graph is moved aside, never deleted.

A relative ``state_path`` lives under the user's state directory,
``$XDG_STATE_HOME/thermal-comp`` (default ``~/.local/state/thermal-comp``), so a shipped
cell file needs no fixed path in the shared system temporary directory.
"""
from __future__ import annotations

import math
import os
import pathlib

from talc_model.model_persistence import ModelStateError, model_identity, read_state

APP_DIR = "thermal-comp"


def state_dir() -> pathlib.Path:
    """``$XDG_STATE_HOME/thermal-comp`` (XDG Base Directory spec; default ``~/.local/state``)."""
    base = os.environ.get("XDG_STATE_HOME", "")
    root = pathlib.Path(base) if base and os.path.isabs(base) else pathlib.Path.home() / ".local" / "state"
    return root / APP_DIR


def resolve_state_path(text: str) -> pathlib.Path | None:
    """The state file for parameter text ``text`` ('' = no persistence): ``~`` expanded, a
    relative path placed under :func:`state_dir`. Its directory is created private (0700)."""
    if not text:
        return None
    path = pathlib.Path(text).expanduser()
    if not path.is_absolute():
        path = state_dir() / path
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    return path


def saved_time_s(path: pathlib.Path, model) -> float | None:
    """The model time a state was saved at (``extra.model_time_s``, else the model's last
    input time), or None when unknown."""
    try:
        t = read_state(path).get("extra", {}).get("model_time_s")
    except ModelStateError:
        t = None
    if t is None:
        t = getattr(model, "t_last", None)
    try:
        t = float(t)
    except (TypeError, ValueError):
        return None
    return t if math.isfinite(t) else None


def run_identity(config, fresh) -> dict[str, list]:
    """The identity values a resumed state may have in a run of ``config`` whose fresh model
    would be ``fresh``: its inputs (or the configuration's ``type_input_names``: a TALC state
    started from the type's prior), its soft-sensor twin, its prior's machine."""
    ident = model_identity(fresh)
    return {"input_names": [ident["input_names"], [str(n) for n in (config or {}).get("type_input_names") or []]],
            "type_model": [ident["type_model"]], "machine": [ident["machine"]]}


def move_aside(path: pathlib.Path, saved_s: float) -> pathlib.Path:
    """Rename a refused state to ``<stem>.refused-t<saved s>[-n]<suffix>`` beside it."""
    n = 0
    while True:
        tag = f".refused-t{saved_s:.0f}" + (f"-{n}" if n else "")
        target = path.with_name(f"{path.stem}{tag}{path.suffix}")
        if not target.exists():
            os.replace(path, target)
            return target
        n += 1
