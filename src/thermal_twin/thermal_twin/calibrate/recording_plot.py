"""PNG overview of a recording: inputs, temperature readings and error components over time."""
from __future__ import annotations

import pathlib

import numpy as np

from thermal_comp_common.recording_csv import Recording, error_unit


def plot_recording(rec: Recording, path: str | pathlib.Path, title: str = "") -> pathlib.Path:
    import matplotlib  # heavy: matplotlib only when plotting
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting

    h = rec.time_s / 3600.0
    fig, axes = plt.subplots(3, 1, figsize=(12, 9), sharex=True, constrained_layout=True)
    ax = axes[0]
    for name, v in rec.inputs.items():
        span = np.nanmax(v) - np.nanmin(v)
        if span > 0:
            ax.plot(h, (v - np.nanmin(v)) / span, lw=0.8, label=f"{name} [{np.nanmin(v):.3g}..{np.nanmax(v):.3g}]")
    ax.set_ylabel("inputs (scaled 0-1)")
    ax.legend(fontsize=7, ncol=3, loc="upper right")
    ax = axes[1]
    for name, v in rec.sensors.items():
        ax.plot(h, v, lw=0.7, label=name[:-2])
    ax.set_ylabel("sensor readings [degC]")
    ax.legend(fontsize=6, ncol=8, loc="upper right")
    ax = axes[2]
    for name, v in rec.errors.items():
        ax.plot(h, v, lw=0.9, label=f"{name} [{error_unit(name)}]")
    ax.set_ylabel("true errors [um, um/m]")
    ax.set_xlabel("time [h]")
    ax.legend(fontsize=7, ncol=4, loc="upper right")
    for a in axes:
        a.grid(alpha=0.3)
    fig.suptitle(title or rec.source)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
