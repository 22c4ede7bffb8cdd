"""The prior learn's adaptive test is against: the type's (its nominal twin's cached prior) or,
with ``--current-prior`` (and ``--current-config``), the prior running now in the cell (online,
after an adoption: the adopted unit's). Checked before the long work, each refusal one line
naming the option and its value: the file is a prior whose content hash and identity hold
(talc_model.prior.talc.load_prior), of the model kind learn builds, whose soft-sensor twin is
the configuration's (talc_model.prior.integrity.check_run) and the ``--twin`` learn starts from
(else the open-loop and the adaptive halves of the test would be against different twins), and
whose model has the configuration's components. No rclpy.
"""
from __future__ import annotations

import hashlib
import pathlib
from dataclasses import dataclass
from typing import Any

import yaml

from talc_model.prior.common import PriorError
from talc_model.prior.dispatch import model_from_prior
from talc_model.prior.integrity import HASH_FIELD, prior_identity
from talc_model.prior.talc import load_prior
from thermal_comp.prior.build import default_config, default_model_kind
from thermal_twin.machine.schema import Machine


@dataclass
class CurrentPrior:
    """A prior (and the configuration it runs with) to test a learned one against."""

    path: str
    sha256: str                 # the prior's own content hash (the audit's), else the file's
    config: dict
    config_path: str            # '' when the configuration is the default for its soft-sensor twin
    prior: dict
    source: str                 # 'type' (the cached type prior) or 'given' (--current-prior)

    def as_dict(self) -> dict[str, Any]:
        return {"prior": self.path, "sha256": self.sha256, "model_config": self.config_path or None,
                "source": self.source, "type_model": prior_identity(self.prior)["type_model"]}


def _same_twin(a: str, b: str) -> bool:
    """Two names of a twin are the same preset or resolve to the same file."""
    if a == b:
        return True
    pa, pb = pathlib.Path(a), pathlib.Path(b)
    return pa.is_file() and pb.is_file() and pa.resolve() == pb.resolve()


def _config(path: str, option: str) -> dict:
    try:
        data = yaml.safe_load(pathlib.Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{option} {path}: not a readable YAML file ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{option} {path}: must hold a mapping, got {type(data).__name__}")
    return data


def load_current(prior_path: str, config_path: str | None, twin: str, machine: Machine) -> CurrentPrior:
    """``--current-prior prior_path [--current-config config_path]`` checked (module docstring);
    ``twin`` is the ``--twin`` argument, ``machine`` its description. ValueError in one line."""
    opt = f"--current-prior {prior_path}"
    try:
        raw = pathlib.Path(prior_path).read_bytes()
    except OSError as exc:
        raise ValueError(f"{opt}: cannot read it ({exc.strerror or exc})") from None
    try:
        prior = load_prior(prior_path)
    except PriorError as exc:
        raise ValueError(f"{opt}: {exc}") from None
    kind = default_model_kind(machine.name)
    if prior.get("model_kind", "talc") != kind:
        raise ValueError(f"{opt}: 'model_kind' is {prior.get('model_kind', 'talc')!r}, learn builds {kind} priors "
                         f"for {machine.name!r}")
    type_model = prior_identity(prior)["type_model"]
    if type_model and not _same_twin(type_model, twin):
        raise ValueError(f"{opt}: its soft-sensor twin 'type_model' is {type_model!r}, not --twin {twin!r} "
                         "(the open-loop and the adaptive tests would be against different twins)")
    if config_path:
        opt = f"--current-config {config_path}"
        config = _config(config_path, "--current-config")
    else:
        config = default_config(type_model or twin, kind)
    try:
        model = model_from_prior(kind, config, prior)
    except (ValueError, TypeError, KeyError) as exc:      # PriorError is a ValueError; a bad config too
        raise ValueError(f"{opt}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    wanted = config.get("component_names")
    if wanted and list(model.component_names) != [str(c) for c in wanted]:
        raise ValueError(f"--current-prior {prior_path}: its components {list(model.component_names)} are not "
                         f"the configuration's {list(wanted)}")
    digest = str(prior.get(HASH_FIELD) or hashlib.sha256(raw).hexdigest())
    return CurrentPrior(str(prior_path), digest, config, str(config_path or ""), prior, "given")


def type_current(path: pathlib.Path, config: dict) -> CurrentPrior:
    """The type's cached prior as the prior to test against (no ``--current-prior``)."""
    prior = load_prior(path)
    digest = str(prior.get(HASH_FIELD) or hashlib.sha256(path.read_bytes()).hexdigest())
    return CurrentPrior(str(path), digest, config, "", prior, "type")
