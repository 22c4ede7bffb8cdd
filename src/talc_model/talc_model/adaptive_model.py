"""The interface every adaptive thermal-error model implements, and the model registry.

The ``talc_model`` node, the replay simulator and the benchmarks drive any model only
through :class:`AdaptiveModel`:

- ``update_inputs(t_s, temperatures, machine_state)`` every time new inputs arrive
  (temperatures by sensor id in degC, NaN = unavailable or excluded; machine_state holds
  numeric inputs such as ``spindle_rpm``);
- ``predict(t_s)`` -> (value, standard uncertainty) per error component (NaN std if the
  model cannot tell);
- ``probe_due(t_s)``: the model's own probing schedule (calibration / compensation /
  no-good phases, recalibration);
- ``add_measurement(t_s, measured, applied_compensation)``: ``measured`` is what the probe
  saw, i.e. the residual after compensation; the total (uncompensated) error the model
  learns from is ``measured + applied_compensation`` (Blaser thesis §6.2.4);
- ``add_failed_measurement(t_s, reason)``: counted, never learned from;
- ``status(t_s)`` -> :class:`ModelStatusData`;
- ``to_state()`` / ``from_state(state)``: a JSON-serialisable dict for atomic persistence.

Persistence has one naming everywhere in this package: ``to_state()`` / ``from_state(state)``
in memory (models and their parts: ARX models, GPs, characteristic diagrams), and
``save_model(path, model)`` / ``load_model(path)`` for files (``model_persistence``).

Concrete models register themselves with ``@register_model("kind")``;
:func:`make_model` builds one from a kind and a configuration mapping. A kind that is not
registered yet is looked up by importing ``talc_model.<module>`` from
:data:`PROVIDER_MODULES` (so neither model module has to import the other). A model started
from a prior of its type (``talc_model.prior``) registers with ``@register_prior_model("kind")``;
the base class's ``from_state`` hands a state that carries a ``prior`` to that class, found the
same way (:data:`PRIOR_PROVIDER_MODULES`), so a base model never imports its prior variant.
"""
from __future__ import annotations

import importlib
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Mapping, Protocol, runtime_checkable
from thermal_comp_common.components import ANGULAR_COMPONENTS, FIVE_AXIS_COMPONENTS, is_angular  # noqa: F401 (re-exported)

#: Phases reported in :attr:`ModelStatusData.phase` (ModelStatus.PHASE_* in the message).
PHASE_CALIBRATION = "calibration"
PHASE_COMPENSATION = "compensation"
PHASE_NO_GOOD = "no_good"
PHASES = (PHASE_CALIBRATION, PHASE_COMPENSATION, PHASE_NO_GOOD)


@dataclass
class ModelStatusData:
    """State of an adaptive model, mirrored 1:1 into thermal_comp_msgs/ModelStatus."""

    phase: str
    probing_cycles: int = 0
    failed_probing_cycles: int = 0
    no_good_phases: int = 0
    parameter_updates: int = 0
    training_samples: int = 0
    q_prod_pct: float = 100.0
    next_probing_due_s: float = math.inf
    max_uncertainty: float = math.nan
    excluded_sensor_ids: list[str] = field(default_factory=list)
    message: str = ""

    def __post_init__(self) -> None:
        if self.phase not in PHASES:
            raise ValueError(f"ModelStatusData.phase: {self.phase!r} is not one of {list(PHASES)}")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@runtime_checkable
class AdaptiveModel(Protocol):
    """What the node and the replay simulator need from an adaptive model."""

    kind: str
    component_names: list[str]

    def update_inputs(self, t_s: float, temperatures: Mapping[str, float],
                      machine_state: Mapping[str, float]) -> None: ...

    def predict(self, t_s: float) -> tuple[dict[str, float], dict[str, float]]: ...

    def probe_due(self, t_s: float) -> bool: ...

    def add_measurement(self, t_s: float, measured: Mapping[str, float],
                        applied_compensation: Mapping[str, float]) -> None: ...

    def add_failed_measurement(self, t_s: float, reason: str) -> None: ...

    def status(self, t_s: float) -> ModelStatusData: ...

    def to_state(self) -> dict: ...

    @classmethod
    def from_state(cls, state: dict) -> "AdaptiveModel": ...


#: kind -> model class. Filled by :func:`register_model`.
MODEL_REGISTRY: dict[str, type] = {}

#: kind -> module that registers it when imported (lazy, avoids import cycles).
PROVIDER_MODULES: dict[str, str] = {
    "talc": "talc_model.talc.model",
    "agp": "talc_model.agp.model",
    "gp_static": "talc_model.agp.model",
    "cd": "talc_model.cd.model",
    "probe_gain_update": "talc_model.open_loop.probe_gain_update",
    "probe_refit": "talc_model.open_loop.probe_refit",
    "load_bucket": "talc_model.open_loop.load_probing",
}


def register_model(kind: str) -> Callable[[type], type]:
    """Class decorator: make ``cls`` available to :func:`make_model` as ``kind``.

    The class needs a constructor ``cls(config: Mapping)`` (or a classmethod
    ``from_config(config)``) and ``from_state(state)``.
    """
    def _register(cls: type) -> type:
        existing = MODEL_REGISTRY.get(kind)
        if existing is not None and existing is not cls and \
                (existing.__module__, existing.__qualname__) != (cls.__module__, cls.__qualname__):
            raise ValueError(f"model kind {kind!r} is already registered by "
                             f"{existing.__module__}.{existing.__qualname__}")
        MODEL_REGISTRY[kind] = cls
        if getattr(cls, "kind", None) is None:
            cls.kind = kind
        return cls
    return _register


def _registered(registry: dict[str, type], providers: Mapping[str, str], kind: str, what: str) -> type:
    """``registry[kind]``, importing its provider module first if it is not registered yet."""
    if kind not in registry and kind in providers:
        importlib.import_module(providers[kind])
    try:
        return registry[kind]
    except KeyError:
        known = sorted(set(registry) | set(providers))
        raise ValueError(f"model_kind: {kind!r} is not a known {what} (known: {known})") from None


def model_class(kind: str) -> type:
    """The class registered for ``kind`` (importing its provider module if needed)."""
    return _registered(MODEL_REGISTRY, PROVIDER_MODULES, kind, "model kind")


#: kind -> the class of a model of that kind started from a prior. Filled by :func:`register_prior_model`.
PRIOR_MODEL_REGISTRY: dict[str, type] = {}

#: kind -> module that registers its prior-started class when imported.
PRIOR_PROVIDER_MODULES: dict[str, str] = {
    "talc": "talc_model.prior.talc",
    "agp": "talc_model.prior.agp",
    "cd": "talc_model.prior.cd",
}


def register_prior_model(kind: str) -> Callable[[type], type]:
    """Class decorator: ``cls`` (a subclass of the ``kind`` model) restores every state of
    ``kind`` that carries a ``prior``; the base class's ``from_state`` delegates to it."""
    def _register(cls: type) -> type:
        PRIOR_MODEL_REGISTRY[kind] = cls
        return cls
    return _register


def prior_model_class(kind: str) -> type:
    """The class registered for models of ``kind`` started from a prior."""
    return _registered(PRIOR_MODEL_REGISTRY, PRIOR_PROVIDER_MODULES, kind, "model kind with a prior")


def make_model(kind: str, config: Mapping[str, Any] | None = None) -> AdaptiveModel:
    """Build a fresh model of ``kind`` from a configuration mapping (unknown keys raise)."""
    cls = model_class(kind)
    config = dict(config or {})
    factory = getattr(cls, "from_config", None)
    return factory(config) if callable(factory) else cls(config)


def model_from_state(state: Mapping[str, Any]) -> AdaptiveModel:
    """Rebuild a model from ``to_state()`` output; the state must carry its ``kind``."""
    kind = state.get("kind")
    if not isinstance(kind, str):
        raise ValueError(f"model state: key 'kind' missing or not a string (got {kind!r})")
    return model_class(kind).from_state(dict(state))
