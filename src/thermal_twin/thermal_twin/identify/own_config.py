"""The model configuration a twin file carries beside it: ``twin init`` (and ``learn``) write
``model_config.yaml`` into the twin's folder, naming that twin as the soft-sensor twin
(``type_model``). ``prior`` and ``learn`` take it for that twin instead of the shipped
configuration of a preset whose name the twin may share. Light (yaml only): the prior's command
line reads it. No rclpy.
"""
from __future__ import annotations

import pathlib

import yaml

MODEL_CONFIG = "model_config.yaml"


def own_model_config(twin_path: str | pathlib.Path | None) -> dict | None:
    """The configuration beside the twin file ``twin_path`` whose ``type_model`` is that file
    (resolved; or a file of the twin's name that no longer exists: the folder was moved), with
    ``type_model`` set to the twin's absolute path; None when there is none (a preset name, no
    file beside it, or one for another twin). A file beside it that is not a YAML mapping is
    refused in one line (ValueError naming it)."""
    if twin_path is None:
        return None
    twin = pathlib.Path(twin_path)
    cfg_path = twin.with_name(MODEL_CONFIG)
    if twin.suffix not in (".yaml", ".yml") or not twin.is_file() or not cfg_path.is_file():
        return None
    try:
        cfg = yaml.safe_load(cfg_path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{cfg_path}: not a readable YAML file ({str(exc).splitlines()[0]})") from None
    if not isinstance(cfg, dict):
        raise ValueError(f"{cfg_path}: must hold a mapping, got {type(cfg).__name__}")
    named = cfg.get("type_model")
    if not isinstance(named, str) or not named:
        return None
    target = pathlib.Path(named) if pathlib.Path(named).is_absolute() else cfg_path.parent / named
    moved = not target.exists() and target.name == twin.name      # the folder was moved as a whole
    if not moved and (not target.is_file() or target.resolve() != twin.resolve()):
        return None
    cfg["type_model"] = str(twin.resolve())
    return cfg


def unit_config(config: dict, unit_twin: str | pathlib.Path) -> dict:
    """``config`` with ``unit_twin`` as its soft-sensor twin (a unit learned from the twin keeps
    its nodes, so its soft sensors are the same names on the unit's twin)."""
    return {**config, "type_model": str(pathlib.Path(unit_twin).resolve())}
