"""The machine's frames on ROS: the static TF publisher of the frame tree
(:mod:`thermal_comp_common.frames`) and where a description comes from."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "description": ["load_description"],
})
