"""A Python API over a running cell (as nav2_simple_commander is for navigation): start or attach,
wait for it, probe, read the model's status and predictions, tighten the bridge's limits, stop."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "cell": ["Cell", "CellError", "BRIDGE_LIMITS", "probe_goal", "validated_tightening"],
    "demo": ["demo_cell"],
    "graph": ["CellTimeout", "GraphSnapshot", "GraphView"],
    "results": ["Errors", "ProbeResult", "Status"],
})
