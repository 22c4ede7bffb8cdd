"""What every prior carries to be trusted, and the checks before one is used: its identity
(machine type, model kind, soft-sensor twin ``type_model``, input names, format version), a
content hash, the run's match to it and a bounded prediction on its own held-out training
programme (TALC, AGP, CD; for TALC also stable poles). Every refusal is one line naming the file or field.
No rclpy here. docs/prior.md, section "Integrity".
"""
from __future__ import annotations

import json
import math
from typing import Any, Callable, Mapping

import numpy as np

from talc_model.agp.gaussian_process import ArdGaussianProcess
from talc_model.arx.model import ArxModel
from talc_model.cd.diagram import CharacteristicDiagram
from talc_model.model_persistence import content_hash
from talc_model.prior.common import PRIOR_VERSION, PriorError

#: the field of a prior file holding the SHA-256 of the rest of it (canonical JSON)
HASH_FIELD = "sha256"
#: the prior's prediction (TALC: simulation) on its held-out training programme (fitted on it too) may err
#: (P99 of |residual|) at most this multiple of that programme's uncompensated P99 |error| plus
#: TRAINING_FLOOR: a prior that errs twice as much as no compensation where it was trained is
#: broken; a weak but sound one (the thesis's three sensors on a small component) stays below it
TRAINING_BOUND = 2.0
#: um (um/m): the allowance of a component that hardly moves on the training programme
TRAINING_FLOOR = 1.0
#: the held-out training programme kept in a TALC prior for that check (rows of its input grid)
TRAINING_ROWS = 2000


def prior_identity(prior: Mapping[str, Any]) -> dict[str, Any]:
    """The identity a prior's content implies (the ``identity`` block a file must carry)."""
    kind = prior.get("model_kind", "talc")
    if kind == "talc":
        state = prior.get("talc_state") or {}
        type_model, inputs = (state.get("config") or {}).get("type_model") or "", state.get("input_names")
    elif kind == "cd":
        type_model, inputs = (prior.get("cd_config") or {}).get("type_model") or "", prior.get("candidate_names")
    else:
        type_model, inputs = "", prior.get("input_names")
    ident = {"format_version": PRIOR_VERSION, "machine": prior.get("machine", ""), "model_kind": kind,
             "type_model": str(type_model), "input_names": [str(n) for n in (inputs or [])]}
    if prior.get("prior_source"):      # not the type's twin: e.g. "history" (talc_model.prior.history)
        ident["prior_source"] = str(prior["prior_source"])
    return ident


def stamped(prior: Mapping[str, Any]) -> dict[str, Any]:
    """``prior`` as written to a file: its identity block and the content hash (computed on the
    JSON round trip, which is what a reader hashes)."""
    doc = json.loads(json.dumps({k: v for k, v in prior.items() if k != HASH_FIELD}, allow_nan=True))
    doc["identity"] = prior_identity(doc)
    doc[HASH_FIELD] = content_hash(doc, HASH_FIELD)
    return doc


def verify_file(where: str, data: Mapping[str, Any]) -> None:
    """Refuse (PriorError, one line naming ``where`` and the field) a prior file whose hash or
    identity block does not match its content."""
    if HASH_FIELD not in data:
        raise PriorError(f"prior {where}: no {HASH_FIELD!r} field: written before priors carried a content "
                         "hash, integrity cannot be checked; rebuild it with thermal-comp prior")
    if data[HASH_FIELD] != content_hash(data, HASH_FIELD):
        raise PriorError(f"prior {where}: field {HASH_FIELD!r} does not match the content: "
                         "the file was changed after it was written")
    found, implied = data.get("identity") or {}, prior_identity(data)
    for key, value in implied.items():
        if found.get(key) != value:
            raise PriorError(f"prior {where}: identity {key!r} is {found.get(key)!r}, its content says {value!r}")


def check_run(prior: Mapping[str, Any], config: Mapping[str, Any]) -> None:
    """Refuse a prior whose soft-sensor twin or inputs are not the run's: ``config`` (the run's
    model configuration) names a ``type_model`` or ``input_names`` / ``type_input_names``
    different from the prior's (compared where both name one)."""
    ident = prior_identity(prior)
    run_type = str(config.get("type_model") or "")
    if run_type and ident["type_model"] and run_type != ident["type_model"]:
        raise PriorError(f"prior: 'type_model' is {ident['type_model']!r}, the run's is {run_type!r} "
                         "(the prior was built on another twin's soft sensors)")
    if ident["model_kind"] != "talc" or not ident["input_names"]:
        return
    allowed = [list(map(str, config[k])) for k in ("input_names", "type_input_names") if config.get(k)]
    if allowed and ident["input_names"] not in allowed:
        raise PriorError(f"prior: 'input_names' are {ident['input_names']}, the run's are "
                         f"{' or '.join(map(str, allowed))}")


def training_check(models: Mapping[str, Any], u: np.ndarray, errors: Mapping[str, np.ndarray],
                   label: str) -> dict[str, Any]:
    """What a prior keeps of its held-out training programme ``label`` (input grid ``u``, true
    errors on it; ``models``: its components) to check its models before use: at most
    TRAINING_ROWS rows, the uncompensated P99 |error| per component."""
    n = min(TRAINING_ROWS, u.shape[0])
    return {"programme": label, "u": np.round(u[:n], 6).tolist(),
            "errors": {c: np.round(np.asarray(errors[c][:n], float), 6).tolist() for c in models},
            "uncompensated_p99": {c: _p99(errors[c][:n]) for c in models}}


def _p99(x) -> float:
    x = np.abs(np.asarray(x, float))
    x = x[np.isfinite(x)]
    return float(np.percentile(x, 99)) if x.size else float("nan")


def check_prior(prior: Mapping[str, Any]) -> None:
    """The checks a prior passes before use that need no run (:func:`check_talc_models`, or the
    AGP's GPs / the CD's diagrams on its ``training_check``); a malformed one is refused naming
    the field."""
    kind = prior.get("model_kind", "talc")
    try:
        if kind == "talc":
            models = {c: ArxModel.from_state(m) for c, m in prior["talc_state"]["models"].items()}
        elif kind == "agp":
            gps = {c: ArdGaussianProcess.from_state(s) for c, s in prior["gps"].items()}
            predict = {c: (lambda u, gp=gp: gp.predict(u)[0]) for c, gp in gps.items()}
        elif kind == "cd":
            cds = {c: (CharacteristicDiagram.from_state(s), list(prior["inputs"][c])) for c, s in prior["cds"].items()}
            predict = {c: (lambda u, cd=cd, cols=cols: cd.predict(u[:, cols])) for c, (cd, cols) in cds.items()}
        else:
            raise PriorError(f"prior: 'model_kind' {kind!r} is none of talc, agp, cd")
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise PriorError(f"prior: {kind} models are not readable ({exc!r})") from None
    if kind == "talc":
        check_talc_models(models, prior.get("training_check"))
    else:
        check_predictions(predict, prior.get("training_check"))


def check_predictions(predict: Mapping[str, Callable[[np.ndarray], np.ndarray]],
                      check: Mapping[str, Any] | None) -> None:
    """Refuse predictors (component -> inputs rows -> prediction) whose P99 |residual| on the
    prior's held-out training programme exceeds the bound of :func:`_within_bound`."""
    if not check:
        return
    u = np.asarray(check["u"], float)
    for c, f in predict.items():
        y = np.asarray(check["errors"][c], float)
        if u.ndim != 2 or u.shape[0] != y.size:
            raise PriorError(f"prior: 'training_check' of {c!r} has {y.size} errors for {u.shape[0]} input rows")
        try:
            with np.errstate(all="ignore"):
                pred = np.asarray(f(u), float).ravel()
        except (ValueError, IndexError) as exc:
            raise PriorError(f"prior: component {c!r} cannot predict its training programme ({exc})") from None
        _within_bound(c, _p99(y - pred) if pred.size == y.size else math.nan, check)


def _within_bound(c: str, err: float, check: Mapping[str, Any]) -> None:
    bound = TRAINING_BOUND * float(check["uncompensated_p99"][c]) + TRAINING_FLOOR
    if not err <= bound:
        raise PriorError(f"prior: component {c!r} errs P99 {err:.4g} on its training programme "
                         f"{check.get('programme', '')!r}, above the bound {bound:.4g} "
                         f"({TRAINING_BOUND:g} x uncompensated {float(check['uncompensated_p99'][c]):.4g} "
                         f"+ {TRAINING_FLOOR:g})")


def check_talc_models(models: Mapping[str, Any], check: Mapping[str, Any] | None) -> None:
    """Refuse TALC prior models (ArxModel per component) with a pole on or outside the unit
    circle or, with the prior's ``training_check``, a simulation on its held-out training
    programme beyond the bound of :func:`_within_bound`."""
    for c, m in models.items():
        poles = m.poles()
        if poles.size and not np.all(np.abs(poles) < 1.0):
            raise PriorError(f"prior: component {c!r}: ARX pole of radius {float(np.max(np.abs(poles))):.4g} "
                             "is not inside the unit circle")
    if not check:
        return
    u = np.asarray(check["u"], float)
    for c, m in models.items():
        y = np.asarray(check["errors"][c], float)
        lag = m.orders.max_lag
        if u.ndim != 2 or u.shape[0] != y.size or u.shape[0] <= lag:
            raise PriorError(f"prior: 'training_check' of {c!r} has {y.size} errors for {u.shape[0]} input rows")
        with np.errstate(all="ignore"):
            err = _p99((y - m.simulate(u, np.zeros(lag), lag))[lag:])
        _within_bound(c, err, check)
