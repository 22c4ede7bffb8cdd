"""Predicted thermal errors to bounded, rate-limited CNC axis offsets over OPC UA.

ROS-free (the node is ``cnc_bridge.cnc_bridge_node``): :class:`BridgeCore` is the whole write
path (transform, safety envelope, write with read-back, audit, ramp-down) around a backend
from :func:`make_backend`. Names load on first use, so ``import cnc_bridge`` pulls in neither
asyncua nor rclpy. Example::

    core = BridgeCore(SafetyEnvelope(EnvelopeConfig(abs_limit_um=30.0)), TwinBackend(),
                      AuditLog("audit.csv"))
    errors = {"E_X0C": 4.0, "E_Y0C": 0.0, "E_Z0T": -2.0, "E_R0T": 0.0,   # um
              "E_A0C": 0.0, "E_B0C": 0.0, "E_C0C": 0.0}                  # um/m
    update = core.update(300.0, errors, {"X": 0.0, "Y": 0.0, "Z": 0.0}, fresh=True)
"""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    # the write path and its /diagnostics status
    "bridge_core": ["AppliedAxis", "BridgeCore", "BridgeCounters", "BridgeUpdate"],
    "status": ["bridge_status"],
    # predicted errors -> axis offsets
    "error_transform": ["HtmGeometry", "LatheToolOffsets", "ToolOffsetModel", "TransformInputError",
                        "fit_tool_offset_model", "five_axis_offsets_um", "offsets_from_errors"],
    # the safety envelope and its flags
    "safety_envelope": ["AxisDecision", "EnvelopeConfig", "EnvelopeConfigError", "HeldAdoption",
                        "SafetyEnvelope", "flag_names", "LIMIT_NONE", "LIMIT_ABSOLUTE", "LIMIT_RATE",
                        "LIMIT_WATCHDOG", "LIMIT_DISABLED", "LIMIT_WRITE_FAILED"],
    # machines
    "offset_backend": ["CncBackend", "TwinBackend", "adopt_held_state", "make_backend"],
    "opcua_config": ["AxisNodes", "OpcUaConfig", "OpcUaConfigError", "default_node_map", "load_node_map"],
    "opcua_backend": ["OpcUaBackend"],
    "credentials": ["Credentials", "CredentialsError", "load_credentials"],
    # records
    "audit_log": ["AuditLog", "read_audit_log"],
    "update_profile": ["UpdateProfile", "read_profile"],
})
