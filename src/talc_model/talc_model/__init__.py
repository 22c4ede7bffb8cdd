"""Adaptive thermal-error models: TALC (ARX), adaptive Gaussian process, characteristic diagrams.

ROS-free (the node is ``talc_model.talc_model_node``). The adaptive models share one streaming
protocol, :class:`AdaptiveModel`; the batch estimators follow scikit-learn's conventions;
persistence is ``to_state()`` / ``from_state()`` in memory and ``save_model`` / ``load_model``
for files. Names load on first use, so the node's ``import talc_model.talc.model`` does not pull in
scikit-learn. Example without ROS: docs/models_without_ros.md.
"""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    # the streaming protocol, the registry, persistence
    "adaptive_model": ["AdaptiveModel", "ModelStatusData", "make_model", "model_from_state", "register_model"],
    "model_persistence": ["ModelStateError", "load_model", "load_pretrained", "save_model"],
    # TALC and its ARX models
    "talc.model": ["TalcModel"],
    "talc.config": ["TalcConfig"],
    "arx.model": ["ArxModel", "ArxOrders", "fit_arx"],
    "arx.order_selection": ["select_orders"],
    # adaptive Gaussian process
    "agp.model": ["AdaptiveGaussianProcess", "AgpConfig", "StaticGaussianProcess"],
    "agp.gaussian_process": ["ArdGaussianProcess"],
    "agp.offset_model": ["OffsetModel"],
    # characteristic diagrams
    "cd.model": ["CdConfig", "CharacteristicDiagramModel"],
    "cd.diagram": ["CharacteristicDiagram", "load_case_update"],
    "cd.input_selection": ["forward_selection", "stability_selection"],
    "cd.measurement_update": ["measurement_update"],
    # open-loop regression on lagged temperatures
    "open_loop.lagged_temperature_model": ["LaggedTemperatureModel"],
    # open-loop ridges adapted by the probes, and load-driven probing from a token bucket
    "open_loop.probe_gain_update": ["ProbeGainUpdateModel"],
    "open_loop.probe_refit": ["ProbeRefitModel"],
    "open_loop.load_probing": ["LoadBucketProbing"],
    # general pieces around any model
    "probing.load_driven": ["LoadDrivenProbing"],
    "loop.slow_error_filter": ["SlowErrorFilter", "slow_error_compensation"],
    "probing.probe_update": ["ProbeSchedule", "run_probe_updates"],
    "probing.uncertainty_weighted_hold": ["measured_hold_rate", "uncertainty_weighted_hold"],
    "open_loop.sensor_selection": ["fast_sensor", "sensor_groups", "sensor_medoids"],
})
