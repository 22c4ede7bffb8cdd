"""A starting twin for a machine without a preset (``thermal-comp twin init``): a description
of where the sensors sit and what heats what, a recording, and a lumped twin identified on it."""
from thermal_twin.identify.command import TWIN_FILE, init_twin, read_recording
from thermal_twin.identify.description import Description, DescriptionError, load_description, parse_description
from thermal_twin.identify.identify import Identification, identify

__all__ = ["TWIN_FILE", "Description", "DescriptionError", "Identification", "identify", "init_twin",
           "load_description", "parse_description", "read_recording"]
