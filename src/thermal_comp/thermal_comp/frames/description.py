"""Where a machine's frame description comes from: a twin preset by name or a YAML file."""
from __future__ import annotations

import pathlib
from typing import Any

import yaml

from thermal_comp_common.frames import FrameError
from thermal_twin.machine.presets import preset_names, preset_path


def load_description(machine: str) -> dict[str, Any]:
    """The parsed YAML of a twin preset (``nmv5000``) or of a file with ``nodes`` / ``sensors``
    (``position_mm``); FrameError naming the argument if neither."""
    path = pathlib.Path(machine)
    if not path.is_file():
        if machine.replace("-", "_") not in {n.replace("-", "_") for n in preset_names()}:
            raise FrameError(f"machine {machine!r}: neither a file nor a twin preset "
                             f"(presets: {', '.join(preset_names())})")
        path = preset_path(machine)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise FrameError(f"machine {machine!r}: {exc.strerror}") from None
    except yaml.YAMLError as exc:
        raise FrameError(f"machine {machine!r}: not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise FrameError(f"machine {machine!r}: the file holds no mapping")
    return data
