"""ROS messages as plain Python data and YAML text (rosidl_runtime_py is not available here)."""
from __future__ import annotations

import array
import math
from typing import Any

import yaml


def message_to_dict(msg: Any) -> Any:
    """Recursively convert a ROS message (or a value inside one) to dicts, lists and scalars."""
    if hasattr(msg, "get_fields_and_field_types"):
        return {name: message_to_dict(getattr(msg, name)) for name in msg.get_fields_and_field_types()}
    if isinstance(msg, (list, tuple, array.array)):
        return [message_to_dict(v) for v in msg]
    if hasattr(msg, "tolist"):  # numpy arrays of fixed-size fields
        return [message_to_dict(v) for v in msg.tolist()]
    if isinstance(msg, bytes):
        return list(msg)
    return msg


class _Dumper(yaml.SafeDumper):
    pass


def _float(dumper, value: float):
    if math.isnan(value):
        return dumper.represent_scalar("tag:yaml.org,2002:float", ".nan")
    if math.isinf(value):
        return dumper.represent_scalar("tag:yaml.org,2002:float", ".inf" if value > 0 else "-.inf")
    return dumper.represent_scalar("tag:yaml.org,2002:float", repr(value))


_Dumper.add_representer(float, _float)


def message_to_yaml(msg: Any) -> str:
    """YAML text of a message, fields in definition order."""
    return yaml.dump(message_to_dict(msg), Dumper=_Dumper, sort_keys=False, default_flow_style=None, width=120)
