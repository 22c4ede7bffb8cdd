"""The model node's side of online learning: a learned prior checked, a model started from it
warmed over the run's history, and swapped in atomically between two instants; audited.

- **Checked** when it is offered (``request``): the prior file's content hash and identity
  (``talc_model.prior.talc.load_prior``); its model configuration must be the run's with at most
  the soft-sensor twin ``type_model`` changed, and the prior's soft-sensor twin must be that
  configuration's (``talc_model.prior.integrity.check_run`` through ``model_from_prior``): the
  learner swaps the soft-sensor twin together with the prior, or the offer is refused in one line.
  Same model kind and components as the running model; one swap at a time; a history that holds
  the whole run.
- **Warmed**: the new model is fed the history (talc_model.online.history) ``per_step`` events per
  modelled instant, so the lock-step is never held for the whole warm-up.
- **Atomic**: when it has caught up with the instant just modelled and no probing cycle is in
  flight, ``step`` hands it over; the node replaces the loop's model before the next instant. Until
  then the running model goes on untouched; a warm-up that fails leaves it in place.
- The bridge and its limits are not touched: the new model's predictions take the same path.
- **Restart**: the adopted configuration is kept beside the model's state file; a node that
  resumes that state runs with it (``resume_config``), since the state's identity names the
  adopted soft-sensor twin and the node's ``model_config`` parameter still names the type's.
No rclpy.
"""
from __future__ import annotations

import json
import pathlib
from dataclasses import dataclass
from typing import Any, Mapping

import yaml

from talc_model.online.audit import append_audit, audit_record
from talc_model.online.history import RunHistory, feed
from talc_model.online.learn_report import figures_of

#: the one configuration key an adopted prior may change: its soft-sensor twin
SWAPPABLE = ("type_model",)
#: beside the model's state file: the configuration of the prior adopted online, which the saved
#: state was made with (a restarted node resumes with it, not with its model_config parameter)
ADOPTED_SUFFIX = ".adopted.yaml"


def adopted_config_path(state_path: pathlib.Path) -> pathlib.Path:
    return state_path.with_name(state_path.name + ADOPTED_SUFFIX)


def resume_config(state_path: pathlib.Path | None, config: dict) -> dict:
    """The configuration a node resuming ``state_path`` runs with: the one adopted online when the
    state was saved after a swap (its file beside the state), else ``config``."""
    if state_path is None or not state_path.is_file() or not adopted_config_path(state_path).is_file():
        return config
    return _load_config(str(adopted_config_path(state_path)))


def write_adopted(state_path: pathlib.Path | None, config: Mapping[str, Any]) -> None:
    """Keep the adopted configuration beside the state file (atomically; None: no state kept)."""
    if state_path is None:
        return
    path = adopted_config_path(state_path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(yaml.safe_dump(dict(config), sort_keys=False))
    tmp.replace(path)


class SwapRefused(ValueError):
    """An offered prior that cannot be adopted (one line)."""


def prior_digest(path: str | pathlib.Path) -> str:
    """The ``sha256`` field of a prior file ('' when it has none or cannot be read)."""
    try:
        data = json.loads(pathlib.Path(path).read_text())
    except (OSError, ValueError):
        return ""
    return str(data.get("sha256", "")) if isinstance(data, dict) else ""


def config_change(run: Mapping[str, Any], new: Mapping[str, Any]) -> str:
    """'' when ``new`` is the run's configuration with at most SWAPPABLE keys changed; else the
    first key that differs, in words."""
    for key in sorted(set(run) | set(new)):
        if key not in SWAPPABLE and run.get(key) != new.get(key):
            return f"key {key!r} is {new.get(key)!r}, the run's is {run.get(key)!r}"
    return ""


@dataclass
class Candidate:
    model: Any
    config: dict
    prior_path: str
    config_path: str
    report_path: str
    sha256: str
    fed: int = 0


@dataclass
class Swapped:
    """A warmed model to install now, and its configuration."""

    model: Any
    config: dict
    audit: dict


def _load_config(path: str) -> dict:
    try:
        data = yaml.safe_load(pathlib.Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise SwapRefused(f"model_config {path!r}: not a readable YAML file ({exc})") from None
    if not isinstance(data, dict):
        raise SwapRefused(f"model_config {path!r}: must hold a mapping, got {type(data).__name__}")
    return data


def _candidate_model(kind: str, config: dict, prior_path: str):
    # heavy (scipy.signal, scikit-learn) and only on an offer: not at the node's start
    from talc_model.prior.dispatch import model_from_prior
    from talc_model.prior.talc import load_prior
    try:
        prior = load_prior(prior_path)
        return model_from_prior(kind, config, prior), str(prior.get("sha256", ""))
    except (ValueError, OSError, KeyError, TypeError) as exc:    # PriorError is a ValueError
        raise SwapRefused(f"prior {prior_path!r}: {exc}") from None


class PriorSwap:
    """See the module docstring. ``config``: the run's model configuration; ``prior_path``: the
    prior the running model started from ('' none); ``audit_path``: the audit file ('' none)."""

    def __init__(self, kind: str, config: Mapping[str, Any], prior_path: str, history: RunHistory,
                 per_step: int = 200, audit_path: str = "", state_path: pathlib.Path | None = None):
        if per_step < 1:
            raise ValueError(f"warm_events_per_instant: {per_step!r} must be >= 1")
        self.kind, self.config, self.history = kind, dict(config), history
        self.per_step, self.audit_path, self.state_path = int(per_step), audit_path, state_path
        self.current_sha256 = prior_digest(prior_path) if prior_path else ""
        self.current_prior = prior_path
        self.candidate: Candidate | None = None

    def request(self, prior_path: str, config_path: str, report_path: str, components, t_s: float) -> tuple[bool, str, str]:
        """An offered prior: (accepted, message, its digest). Refusals are audited."""
        try:
            cand = self._check(prior_path, config_path, report_path, list(components))
        except SwapRefused as exc:
            self._audit("adoption refused", t_s, prior_digest(prior_path), str(exc), report_path)
            return False, str(exc), prior_digest(prior_path)
        self.candidate = cand
        return True, (f"accepted: warming a model from {prior_path} over {len(self.history)} history events, "
                      f"{self.per_step} per instant"), cand.sha256

    def answer(self, req, resp, components, t_s: float):
        """The AdoptPrior service's answer to ``req`` (its fields as in the .srv), filled into ``resp``."""
        old = self.current_sha256
        ok, msg, new = self.request(req.prior_path, req.model_config_path, req.report_path, components, t_s)
        resp.accepted, resp.message, resp.old_prior_sha256, resp.new_prior_sha256 = ok, msg, old, new
        return resp

    def _check(self, prior_path: str, config_path: str, report_path: str, components: list) -> Candidate:
        if self.candidate is not None:
            raise SwapRefused(f"a swap to {self.candidate.prior_path} is still warming")
        if self.history.incomplete:
            raise SwapRefused(f"cannot warm a new model: {self.history.incomplete}")
        config = _load_config(config_path)
        change = config_change(self.config, config)
        if change:
            raise SwapRefused(f"model_config {config_path!r}: {change} (only the soft-sensor twin "
                              f"{'/'.join(SWAPPABLE)} may change with the prior)")
        model, sha = _candidate_model(self.kind, config, prior_path)
        if list(model.component_names) != components:
            raise SwapRefused(f"prior {prior_path!r}: components {list(model.component_names)}, the running "
                              f"model's are {components}")
        return Candidate(model, config, prior_path, config_path, report_path, sha)

    def step(self, t_s: float, probing_busy: bool) -> Swapped | None:
        """After the node modelled ``t_s``: warm the candidate on; the swap when it is due."""
        cand = self.candidate
        if cand is None:
            return None
        events = self.history.events
        try:
            for ev in events[cand.fed:cand.fed + self.per_step]:
                feed(cand.model, ev)
                cand.fed += 1
        except ValueError as exc:
            self.candidate = None
            self._audit("adoption refused", t_s, cand.sha256, f"warm-up failed at history event {cand.fed}: {exc}",
                        cand.report_path)
            return None
        if self.history.incomplete:
            self.candidate = None
            self._audit("adoption refused", t_s, cand.sha256, f"warm-up stopped: {self.history.incomplete}",
                        cand.report_path)
            return None
        if cand.fed < len(events) or probing_busy:
            return None
        self.candidate = None
        record = self._audit("swapped", t_s, cand.sha256, f"model from {cand.prior_path} warmed over "
                             f"{self.history.instants} instants, in use from the instant after {t_s:.0f} s",
                             cand.report_path, prior_path=cand.prior_path, model_config=cand.config_path,
                             type_model=str(cand.config.get("type_model", "")))
        self.current_sha256, self.current_prior, self.config = cand.sha256, cand.prior_path, cand.config
        try:
            write_adopted(self.state_path, cand.config)
        except OSError as exc:
            record["reason"] += f"; the adopted configuration could not be kept beside the state: {exc}"
        return Swapped(cand.model, cand.config, record)

    def _audit(self, event: str, t_s: float, new_sha: str, reason: str, report_path: str, **extra) -> dict:
        record = audit_record(event, t_s, self.current_sha256, new_sha, reason, _report_figures(report_path),
                              source="model node", report=report_path, **extra)
        append_audit(self.audit_path, record)
        return record


def _report_figures(report_path: str) -> dict:
    try:
        doc = json.loads(pathlib.Path(report_path).read_text()) if report_path else {}
    except (OSError, ValueError):
        return {}
    return figures_of(doc) if isinstance(doc, dict) else {}
