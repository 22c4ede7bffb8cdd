"""The axes the emulated CNC has by default: plain data, so that the command's options name them
without loading the OPC UA server."""

DEFAULT_POSITION_AXES = ("X", "Y", "Z", "B", "C")
DEFAULT_COMPENSATION_AXES = ("X", "Y", "Z")
