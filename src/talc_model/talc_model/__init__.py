"""Adaptive thermal-error models: TALC (ARX), adaptive Gaussian process, characteristic diagrams.

ROS-free (the node is ``talc_model.talc_model_node``). The adaptive models share one streaming
protocol, :class:`AdaptiveModel`; the batch estimators follow scikit-learn's conventions;
persistence is ``to_state()`` / ``from_state()`` in memory and ``save_model`` / ``load_model``
for files. Names load on first use, so the node's ``import talc_model.talc`` does not pull in
scikit-learn. Example without ROS: docs/models_without_ros.md.
"""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    # the streaming protocol, the registry, persistence
    "adaptive_model": ["AdaptiveModel", "ModelStatusData", "make_model", "model_from_state", "register_model"],
    "model_persistence": ["ModelStateError", "load_model", "load_pretrained", "save_model"],
    # TALC and its ARX models
    "talc": ["TalcModel"],
    "talc_config": ["TalcConfig"],
    "arx": ["ArxModel", "ArxOrders", "fit_arx"],
    "order_selection": ["select_orders"],
    # adaptive Gaussian process
    "agp": ["AdaptiveGaussianProcess", "AgpConfig", "StaticGaussianProcess"],
    "gaussian_process": ["ArdGaussianProcess"],
    "offset_model": ["OffsetModel"],
    # characteristic diagrams
    "cd_model": ["CdConfig", "CharacteristicDiagramModel"],
    "characteristic_diagram": ["CharacteristicDiagram", "load_case_update"],
    "cd_input_selection": ["forward_selection", "stability_selection"],
    "cd_measurement_update": ["measurement_update"],
    # open-loop regression on lagged temperatures
    "lagged_temperature_model": ["LaggedTemperatureModel"],
    # general pieces around any model
    "load_driven_probing": ["LoadDrivenProbing"],
    "slow_error_filter": ["SlowErrorFilter", "slow_error_compensation"],
    "probe_update": ["ProbeSchedule", "run_probe_updates"],
    "uncertainty_weighted_hold": ["measured_hold_rate", "uncertainty_weighted_hold"],
    "sensor_selection": ["fast_sensor", "sensor_groups", "sensor_medoids"],
})
