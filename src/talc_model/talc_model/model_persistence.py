"""Atomic persistence of adaptive models (state, history, counters) as JSON.

``save_model(path, model)`` writes ``model.to_state()`` wrapped in a small envelope to a
temporary file in the same directory, fsyncs it, renames it over ``path`` with
``os.replace`` (atomic on POSIX) and fsyncs the directory: after a crash, ``path`` holds
either the previous or the new state, never a partial one. ``load_model(path)`` restores
the model exactly (a restart resumes without a new calibration phase);
``load_pretrained(path, config)`` starts a new run from a trained model's parameters.

The envelope carries the model's identity (kind, soft-sensor twin ``type_model``, input names,
the machine of its prior) and the SHA-256 of the rest of it: a changed file is refused in one
line, and a resumed state is checked against the run's identity (:func:`check_identity`). A
state written before the hash existed (version 1) loads with a warning that its integrity was
not checked: refusing it would throw away a machine's learnt model.

JSON is used for readability and diffability; non-finite numbers are written as
``NaN``/``Infinity`` (Python's json dialect) because model states contain them.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import pathlib
import tempfile
from typing import Any, Mapping

from talc_model.adaptive_model import AdaptiveModel, model_class, model_from_state

FORMAT = "thermal_comp.model_state"
FORMAT_VERSION = 2
#: versions read: 1 has no identity and no hash (loaded with a warning)
READ_VERSIONS = (1, 2)
#: the envelope field holding the SHA-256 of the rest of the envelope
HASH_FIELD = "sha256"


class ModelStateError(ValueError):
    """A model state file is missing, unreadable or malformed; the message names it."""


def content_hash(doc: Mapping[str, Any], field: str) -> str:
    """SHA-256 (hex) of ``doc`` without ``field``, as canonical JSON (sorted keys, no spaces)."""
    body = {k: v for k, v in doc.items() if k != field}
    text = json.dumps(body, allow_nan=True, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def model_identity(model: AdaptiveModel) -> dict[str, Any]:
    """What a state must match to be resumed by a run: model kind, soft-sensor twin
    (``type_model``, '' without one), input names ([] while still unknown), its prior's machine."""
    inputs = getattr(model, "input_names", None)
    if not inputs and hasattr(type(model), "candidate_names"):      # the CD model's candidates
        inputs = model.candidate_names
    prior = getattr(model, "prior", None)
    return {"model_kind": model.kind, "type_model": str(getattr(model.config, "type_model", "") or ""),
            "input_names": [str(n) for n in inputs or []],
            "machine": str((prior or {}).get("machine", "")) if isinstance(prior, Mapping) else ""}


def check_identity(path, found: Mapping[str, Any], expected: Mapping[str, list]) -> None:
    """Refuse (ModelStateError, one line naming the field) a state whose identity ``found`` is
    none of the values ``expected`` allows per field; empty values on either side are not compared."""
    for key, allowed in expected.items():
        value, allowed = found.get(key), [a for a in allowed if a]
        if value and allowed and value not in allowed:
            raise ModelStateError(f"{path}: identity {key!r} is {value!r}, the run's is "
                                  f"{' or '.join(map(repr, allowed))}")


def save_model(path: str | os.PathLike, model: AdaptiveModel, extra: Mapping[str, Any] | None = None) -> None:
    """Atomically write the model's state to ``path`` (see the module docstring)."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": FORMAT, "version": FORMAT_VERSION, "kind": model.kind, "identity": model_identity(model),
           "extra": dict(extra or {}), "state": model.to_state()}
    doc = json.loads(json.dumps(doc, allow_nan=True))      # hashed as a reader sees it
    doc[HASH_FIELD] = content_hash(doc, HASH_FIELD)
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
    if doc.get("version") not in READ_VERSIONS:
        raise ModelStateError(f"{path}: key 'version' is {doc.get('version')!r}, expected one of {READ_VERSIONS}")
    if not isinstance(doc.get("state"), dict):
        raise ModelStateError(f"{path}: key 'state' is missing or not an object")
    if doc["version"] == 1:
        logging.getLogger("talc_model").warning(f"{path}: model state of format version 1 has no content hash: "
                                                "its integrity was not checked")
    elif doc.get(HASH_FIELD) != content_hash(doc, HASH_FIELD):
        raise ModelStateError(f"{path}: key {HASH_FIELD!r} does not match the content: the file was changed "
                              "after it was written")
    elif doc.get("kind") != doc["state"].get("kind", doc.get("kind")):
        raise ModelStateError(f"{path}: key 'kind' is {doc.get('kind')!r}, its state's is {doc['state'].get('kind')!r}")
    return doc


def load_model(path: str | os.PathLike, expected_kind: str | None = None,
               expected: Mapping[str, list] | None = None) -> AdaptiveModel:
    """Restore a saved model exactly (phase, history, counters); ``expected``: the identity
    values the run allows per field (:func:`check_identity`), checked on the restored model."""
    doc = read_state(path)
    if expected_kind is not None and doc.get("kind") != expected_kind:
        raise ModelStateError(f"{path}: key 'kind' is {doc.get('kind')!r}, expected {expected_kind!r}")
    try:
        model = model_from_state(doc["state"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelStateError(f"{path}: bad model state: {exc}") from None
    if expected:
        check_identity(path, model_identity(model), expected)
    return model


def load_pretrained(path: str | os.PathLike, config: Mapping[str, Any] | None = None,
                    expected_kind: str | None = None,
                    expected: Mapping[str, list] | None = None) -> AdaptiveModel:
    """Start a new run from a trained model (the class's ``from_pretrained`` if it has one,
    else the restored model as it was saved). ``expected``: the identity values the run allows
    per field (:func:`check_identity`), checked on the trained model as it was saved."""
    doc = read_state(path)
    kind = doc.get("kind")
    if expected_kind is not None and kind != expected_kind:
        raise ModelStateError(f"{path}: key 'kind' is {kind!r}, expected {expected_kind!r}")
    try:
        cls = model_class(kind)
        if expected:
            check_identity(path, model_identity(cls.from_state(doc["state"])), expected)
        factory = getattr(cls, "from_pretrained", None)
        if callable(factory):
            return factory(doc["state"], config)
        return cls.from_state(doc["state"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelStateError(f"{path}: bad pretrained model: {exc}") from None
