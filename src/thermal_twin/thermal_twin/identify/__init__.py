"""A starting twin for a machine without a preset (``thermal-comp twin init``): a description
of where the sensors sit and what heats what, a recording, and a lumped twin identified on it.

Exported lazily: ``thermal-comp twin --help`` imports :mod:`thermal_twin.identify.cli` through this
package and must not load scipy and the simulator behind it."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "command": ["TWIN_FILE", "init_twin", "read_recording"],
    "description": ["Description", "DescriptionError", "load_description", "parse_description"],
    "identification": ["Identification", "identify"],
    "own_config": ["MODEL_CONFIG", "own_model_config", "unit_config"],
})
