"""One set of configuration keys for every replayed model, defaults from the recording, and the
limits a replay states before it runs.

- **Keys**: ``sensors`` (the temperature inputs) and ``components`` (the error components) for
  TALC, the AGP and the characteristic diagram alike. TALC's own names (``input_names``,
  ``component_names``) are still accepted, as deprecated aliases with a warning, for every kind;
  the mapping to each model's own keys is made here, so the models' configs stay as they are.
- **Components** default to the recording's error columns (``ch1_um`` -> ``ch1``), not to the
  thesis machine's names.
- **Characteristic diagram**: its grid has (n_intervals + 1) ^ max_inputs nodes per component;
  more than :data:`CD_MAX_NODES` is reduced (max_inputs lowered, with a warning) instead of a fit
  that does not return.
- **Too short**: a replay whose compensation part is shorter than :data:`MIN_COMPENSATED_SHARE`
  of its time, or that never leaves calibration, gets a warning; so does every component the
  compensation made worse.
"""
from __future__ import annotations

from typing import Any, Mapping

ALIASES = {"input_names": "sensors", "component_names": "components"}
TALC_KEYS = {"sensors": "input_names", "components": "component_names"}
#: largest characteristic-diagram grid fitted (5 ^ 4: max_inputs 4 at the default 4 intervals)
CD_MAX_NODES = 625
MIN_COMPENSATED_SHARE = 0.25


class ConfigKeyError(ValueError):
    """Two spellings of one key, or a bad value; the message names them."""


def canonical_config(kind: str, config: Mapping[str, Any], error_columns: list[str]) -> tuple[dict, list[str]]:
    """The model's own config from the canonical keys (plus deprecated aliases) and the
    recording's error columns; the warnings to print."""
    cfg, warnings = dict(config), []
    for old, new in ALIASES.items():
        if old in cfg:
            if new in cfg:
                raise ConfigKeyError(f"config: both {old!r} and {new!r} given; use {new!r} (one set of keys for "
                                     "talc, agp and cd)")
            warnings.append(f"config key {old!r} is deprecated: use {new!r} (the same for talc, agp and cd)")
            cfg[new] = cfg.pop(old)
    if "components" not in cfg:
        names = [c[:-3] if c.endswith("_um") else c for c in error_columns]
        if names:
            cfg["components"] = names
            warnings.append(f"components from the recording's error columns: {', '.join(names)} "
                            "(set 'components' to choose)")
    if kind == "cd":
        warnings += _cd_limit(cfg)
    if kind == "talc":
        cfg = {TALC_KEYS.get(k, k): v for k, v in cfg.items()}
    return cfg, warnings


def _cd_limit(cfg: dict) -> list[str]:
    k = cfg.get("max_inputs", 3)
    n = cfg.get("n_intervals", 4)
    if not (isinstance(k, int) and isinstance(n, int) and k >= 1 and n >= 1):
        raise ConfigKeyError(f"config: max_inputs {k!r} and n_intervals {n!r} must be integers >= 1")
    if (n + 1) ** k <= CD_MAX_NODES:
        return []
    if n + 1 > CD_MAX_NODES:
        raise ConfigKeyError(f"config: n_intervals {n} gives {n + 1} nodes per input, above the characteristic "
                             f"diagram's limit of {CD_MAX_NODES} nodes per component")
    fit = 1
    while fit < k and (n + 1) ** (fit + 1) <= CD_MAX_NODES:
        fit += 1
    cfg["max_inputs"] = fit
    return [f"characteristic diagram: max_inputs {k} with n_intervals {n} is a grid of {(n + 1) ** k} nodes per "
            f"component, above the limit of {CD_MAX_NODES}: reduced to max_inputs {fit} ({(n + 1) ** fit} nodes)"]


def replay_warnings(summary: Mapping[str, Any]) -> list[str]:
    """Warnings on a finished replay: too short for the model to leave calibration (or leaving
    it with little to score), and every component the compensation made worse (P99)."""
    out = []
    dur = float(summary.get("duration_h") or 0.0)
    cal = summary.get("calibration_h")
    if summary.get("compensation_steps", 0) == 0:
        out.append(f"replay too short: the model did not leave its calibration phase in {dur:.2f} h; nothing was "
                   "compensated (give a longer recording, or start from a prior: --prior)")
    elif dur > 0 and cal is not None and cal == cal and 1.0 - cal / dur < MIN_COMPENSATED_SHARE:
        out.append(f"replay short for this model: calibration took {cal:.2f} h of {dur:.2f} h, only "
                   f"{100 * (1 - cal / dur):.0f} % of the time is compensated; its figures rest on a model fitted "
                   "on little data")
    for c, row in (summary.get("components") or {}).items():
        p, u = row.get("p99"), row.get("p99_uncompensated")
        if p is not None and u is not None and p == p and u == u and p > u:
            out.append(f"component {c}: the compensation made it worse (P99 {u:.2f} -> {p:.2f} {row.get('unit', '')})")
    return out
