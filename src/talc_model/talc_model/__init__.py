"""Adaptive thermal-error models: TALC (ARX), adaptive Gaussian process, characteristic diagrams.

The public API: ``from talc_model import TalcModel, make_model, save_model, ...``. The adaptive
models share one streaming protocol (:class:`AdaptiveModel`: ``update_inputs``, ``predict``,
``probe_due``, ``add_measurement``, ``add_failed_measurement``, ``status``, ``to_state`` /
``from_state``); the batch estimators follow scikit-learn's conventions; persistence is
``to_state()`` / ``from_state()`` in memory and ``save_model`` / ``load_model`` for files.
Example without ROS: docs/models_without_ros.md.

Names are imported on first use (PEP 562), so that ``import talc_model.talc`` in the node
does not pull in scikit-learn for the AGP (several seconds at start-up).
"""
from __future__ import annotations

import importlib
from typing import Any

#: public name -> module that defines it
_EXPORTS: dict[str, str] = {
    # the streaming protocol, the registry, persistence
    "AdaptiveModel": "adaptive_model", "ModelStatusData": "adaptive_model", "make_model": "adaptive_model",
    "model_from_state": "adaptive_model", "register_model": "adaptive_model",
    "save_model": "model_persistence", "load_model": "model_persistence", "load_pretrained": "model_persistence",
    "ModelStateError": "model_persistence",
    # TALC and its ARX models
    "TalcModel": "talc", "TalcConfig": "talc_config",
    "ArxModel": "arx", "ArxOrders": "arx", "fit_arx": "arx", "select_orders": "order_selection",
    # adaptive Gaussian process
    "AdaptiveGaussianProcess": "agp", "StaticGaussianProcess": "agp", "AgpConfig": "agp",
    "ArdGaussianProcess": "gaussian_process", "OffsetModel": "offset_model",
    # characteristic diagrams
    "CharacteristicDiagramModel": "cd_model", "CdConfig": "cd_model",
    "CharacteristicDiagram": "characteristic_diagram", "load_case_update": "characteristic_diagram",
    "forward_selection": "cd_input_selection", "stability_selection": "cd_input_selection",
    "measurement_update": "cd_measurement_update",
    # open-loop regression on lagged temperatures
    "LaggedTemperatureModel": "lagged_temperature_model",
    # general pieces around any model
    "LoadDrivenProbing": "load_driven_probing",
    "SlowErrorFilter": "slow_error_filter", "slow_error_compensation": "slow_error_filter",
    "ProbeSchedule": "probe_update", "run_probe_updates": "probe_update",
    "uncertainty_weighted_hold": "uncertainty_weighted_hold", "measured_hold_rate": "uncertainty_weighted_hold",
    "sensor_groups": "sensor_selection", "sensor_medoids": "sensor_selection", "fast_sensor": "sensor_selection",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'talc_model' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"talc_model.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
