"""A small deterministic synthetic machine for the evaluate tests (no twin run needed)."""
from __future__ import annotations

import numpy as np

from talc_model.open_loop.lagged_temperature_model import exponential_filter


def synthetic(n: int = 900, dt: float = 60.0, seed: int = 0, plateau: bool = False) -> dict[str, np.ndarray]:
    """Load steps drive two temperatures (fast, slow) and a lagged displacement; with
    ``plateau`` the load stops after 10 % of the rows (a long steady state)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    load = np.where((t // 7200) % 2 == 0, 1.0, 0.3) * 3000.0
    if plateau:
        load[n // 10:] = 0.0
    fast = 25 + exponential_filter(t, load / 1000.0 * 4.0, 1200.0)
    slow = 24 + exponential_filter(t, load / 1000.0 * 2.0, 5400.0)
    amb = 22 + 0.3 * np.sin(2 * np.pi * t / 86400.0)
    disp = 3.0 * (fast - 25) + exponential_filter(t, 2.0 * (slow - 24), 3600.0)
    return {"time_s": t, "spindle_rpm": load, "t_fast_c": fast + rng.normal(0, 0.01, n),
            "t_slow_c": slow + rng.normal(0, 0.01, n), "ambient_c": amb,
            "z_um": disp + rng.normal(0, 0.05, n), "x_um": 0.5 * disp + rng.normal(0, 0.05, n)}


def write_csv(path, cols: dict[str, np.ndarray], bom: bool = False, rename: dict[str, str] | None = None) -> None:
    rename = rename or {}
    names = list(cols)
    lines = [",".join(rename.get(c, c) for c in names)]
    lines += [",".join(f"{cols[c][i]:.6g}" for c in names) for i in range(len(cols["time_s"]))]
    text = "\n".join(lines) + "\n"
    path.write_text(("\ufeff" if bom else "") + text, encoding="utf-8")
