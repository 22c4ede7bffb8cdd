"""Atomic persistence of adaptive models (state, history, counters) as JSON.

``save_model(path, model)`` writes ``model.to_state()`` wrapped in a small envelope to a
temporary file in the same directory, fsyncs it, renames it over ``path`` with
``os.replace`` (atomic on POSIX) and fsyncs the directory: after a crash, ``path`` holds
either the previous or the new state, never a partial one. ``load_model(path)`` restores
the model exactly (a restart resumes without a new calibration phase);
``load_pretrained(path, config)`` starts a new run from a trained model's parameters.

JSON is used for readability and diffability; non-finite numbers are written as
``NaN``/``Infinity`` (Python's json dialect) because model states contain them.
"""
from __future__ import annotations

import json
import os
import pathlib
import tempfile
from typing import Any, Mapping

from talc_model.adaptive_model import AdaptiveModel, model_class, model_from_state

FORMAT = "thermal_comp.model_state"
FORMAT_VERSION = 1


class ModelStateError(ValueError):
    """A model state file is missing, unreadable or malformed; the message names it."""


def save_model(path: str | os.PathLike, model: AdaptiveModel, extra: Mapping[str, Any] | None = None) -> None:
    """Atomically write the model's state to ``path`` (see the module docstring)."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": FORMAT, "version": FORMAT_VERSION, "kind": model.kind,
           "extra": dict(extra or {}), "state": model.to_state()}
    text = json.dumps(doc, allow_nan=True, separators=(",", ":"))
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    try:
        dfd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


def read_state(path: str | os.PathLike) -> dict[str, Any]:
    """The envelope of a saved state (keys format, version, kind, extra, state)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ModelStateError(f"{path}: no such model state file")
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelStateError(f"{path}: not a readable model state ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ModelStateError(f"{path}: key 'format' is {doc.get('format') if isinstance(doc, dict) else doc!r}, "
                              f"expected {FORMAT!r}")
    if doc.get("version") != FORMAT_VERSION:
        raise ModelStateError(f"{path}: key 'version' is {doc.get('version')!r}, expected {FORMAT_VERSION}")
    if not isinstance(doc.get("state"), dict):
        raise ModelStateError(f"{path}: key 'state' is missing or not an object")
    return doc


def load_model(path: str | os.PathLike, expected_kind: str | None = None) -> AdaptiveModel:
    """Restore a saved model exactly (phase, history, counters)."""
    doc = read_state(path)
    if expected_kind is not None and doc.get("kind") != expected_kind:
        raise ModelStateError(f"{path}: key 'kind' is {doc.get('kind')!r}, expected {expected_kind!r}")
    try:
        return model_from_state(doc["state"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelStateError(f"{path}: bad model state: {exc}") from None


def load_pretrained(path: str | os.PathLike, config: Mapping[str, Any] | None = None,
                    expected_kind: str | None = None) -> AdaptiveModel:
    """Start a new run from a trained model (the class's ``from_pretrained`` if it has one,
    else the restored model as it was saved)."""
    doc = read_state(path)
    kind = doc.get("kind")
    if expected_kind is not None and kind != expected_kind:
        raise ModelStateError(f"{path}: key 'kind' is {kind!r}, expected {expected_kind!r}")
    try:
        cls = model_class(kind)
        factory = getattr(cls, "from_pretrained", None)
        if callable(factory):
            return factory(doc["state"], config)
        return cls.from_state(doc["state"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelStateError(f"{path}: bad pretrained model: {exc}") from None
