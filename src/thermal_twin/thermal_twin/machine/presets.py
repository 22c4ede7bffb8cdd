"""The packaged machine presets (YAML files in ``thermal_twin/presets/``)."""
from __future__ import annotations

import pathlib

from thermal_twin.machine.spec import MachineSpecError

PRESET_DIR = pathlib.Path(__file__).resolve().parents[1] / "presets"


def preset_names() -> list[str]:
    """Names accepted by ``--machine`` (file stems, '_' written as '-')."""
    return sorted(p.stem.replace("_", "-") for p in PRESET_DIR.glob("*.yaml"))


def preset_path(name: str) -> pathlib.Path:
    """Path of a preset by name (``swiss-lathe`` or ``swiss_lathe``), or a clear error.

    Load it with ``machine_schema.load_machine(name)``, which accepts preset names.
    """
    p = PRESET_DIR / f"{name.replace('-', '_')}.yaml"
    if not p.is_file():
        raise MachineSpecError(f"machine {name!r}: not a preset and not a file "
                               f"(presets: {', '.join(preset_names())})")
    return p
