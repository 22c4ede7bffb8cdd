"""The work of ``thermal-comp twin init`` (:mod:`thermal_twin.identify.cli` parses the arguments):
read the recording and the description, identify the twin, write ``twin.yaml`` (the project's
machine description: ``learn --twin`` and ``prior --machine`` take it like a preset),
``report.json`` and ``report.md`` generated from it. No rclpy.
"""
from __future__ import annotations

import json
import math
import pathlib
import sys
import time
from typing import Any, Callable

import yaml

from thermal_comp_common.json_figures import finite_figures
from thermal_comp_common.bags.recording import BagRecordingError, load_recording
from thermal_comp_common.recording_csv import Recording, RecordingError

from thermal_twin.calibrate.fit import CalibrationError
from thermal_twin.identify.description import Description, DescriptionError, load_description
from thermal_twin.identify.identification import CRITERION, HELD_OUT, identify
from thermal_twin.identify.own_config import MODEL_CONFIG
from thermal_twin.identify.scores import held_out_table
from thermal_twin.machine.schema import load_machine, save_machine
from thermal_twin.machine.spec import MachineSpecError

TWIN_FILE = "twin.yaml"
#: a cell bag's probing results (residuals of a compensated machine are not turned into totals here)
PROBES_TOPIC = "errors/measured"


def read_recording(path: str, hours: float | None = None, sample_period_s: float | None = None) -> Recording:
    """A recording CSV (``sample_period_s``: one without a time column) or a cell bag (probes
    from ``errors/measured``), its first ``hours``."""
    rec = load_recording(path, errors_topic=PROBES_TOPIC, sample_period_s=sample_period_s)
    if hours is not None:
        if not (math.isfinite(hours) and hours > 0):
            raise DescriptionError(f"--hours: {hours!r} must be a number of hours > 0")
        n = int(sum(rec.time_s - rec.time_s[0] <= hours * 3600.0))
        rec = rec.slice(0, n)
    return rec


def init_twin(description: Description | str, rec: Recording, out: pathlib.Path, holdout: float = 0.25,
              max_nfev: int = 40, progress: Callable[[str], None] = lambda m: None) -> dict[str, Any]:
    """Identify the twin and write it with its report into ``out``; the report as a dict."""
    t0 = time.perf_counter()
    d = description if isinstance(description, Description) else load_description(description)
    if not 0.05 <= holdout <= 0.5:
        raise DescriptionError(f"--holdout: {holdout!r} must be within [0.05, 0.5]")
    ident = identify(d, rec, holdout=holdout, max_nfev=max_nfev, progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    spec = dict(ident.spec)
    spec["description"] = (f"lumped twin made by thermal-comp twin init from {rec.source or 'a recording'} "
                           f"({(rec.time_s[-1] - rec.time_s[0]) / 3600.0:.1f} h), {ident.chosen.hidden} hidden bodies")
    path = out / TWIN_FILE
    save_machine(spec, path)
    machine = load_machine(str(path))
    cal = ident.chosen.calibration
    report = {"twin": machine.name, "recording": rec.source, "recording_h": float(rec.time_s[-1] - rec.time_s[0]) / 3600,
              "holdout_fraction": holdout, "hidden_bodies": ident.chosen.hidden,
              "nodes": machine.node_names, "soft_sensors": soft_sensors(machine),
              "chosen_by": ident.chosen_by,
              "candidates": [{"hidden": c.hidden, "parameters": len(c.calibration.estimates),
                              "information_criterion": c.criterion if ident.chosen_by == CRITERION else None,
                              "held_out_score": c.score if ident.chosen_by == HELD_OUT else None}
                             for c in ident.candidates],
              "held_out_score": ident.chosen.score,
              "held_out_rmse": held_out_table(ident, rec),
              "notes": ident.notes + list(rec.warnings),
              "fit": {"twin_runs": cal.n_evals, "simulated_h_per_s": round(cal.simulated_h / max(cal.wall_s, 1e-9), 1)},
              "wall_s": round(time.perf_counter() - t0, 1), "files": {"twin": str(path)}}
    (out / MODEL_CONFIG).write_text(yaml.safe_dump(model_config(d, machine, path), sort_keys=False))
    report["files"]["model_config"] = str(out / MODEL_CONFIG)
    (out / "report.json").write_text(json.dumps(finite_figures(report), indent=1) + "\n")
    (out / "report.md").write_text(markdown(report))
    return report


def soft_sensors(machine) -> list[str]:
    """The twin's nodes a displacement depends on, as TALC soft-sensor names (``type_input_names``):
    a fluid body (no thermo-elastic term) only carries heat to them."""
    used = {n for e in machine.errors.values() for n, g in e.terms if g}
    return [f"twin:{n}" for n in machine.node_names if n in used]


def model_config(d: Description, machine, twin_path: pathlib.Path) -> dict:
    """A TALC configuration for ``prior --machine twin.yaml --config`` (plain data: TALC's own
    defaults for the rest): the displacement channels, the recording's temperature sensors, and
    this twin as the soft-sensor twin with the nodes the errors use."""
    return {"component_names": list(d.displacements),
            "angular_components": [c for c in d.displacements if d.unit(c) == "um/m"],
            "input_names": list(d.sensors),
            "type_model": str(twin_path.resolve()), "type_input_names": soft_sensors(machine)}


def _fmt(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3g}"


def markdown(rep: dict) -> str:
    """report.md, every figure from ``rep`` (report.json)."""
    how = ("every structure fitted on the whole recording, its last 5 % out" if rep["chosen_by"] == CRITERION else
           f"structures fitted on the first {100 * (1 - rep['holdout_fraction']):.0f} %, scored on the rest")
    lines = [f"# twin init: {rep['twin']} from {rep['recording']}", "",
             f"Recording {rep['recording_h']:.1f} h; kept {rep['hidden_bodies']} hidden bodies by the "
             f"{rep['chosen_by']} ({how}); "
             f"nodes {', '.join(rep['nodes'])}. "
             f"Wall {rep['wall_s']} s, twin {rep['fit']['simulated_h_per_s']} simulated h/s.", "",
             "| hidden bodies | parameters | information criterion (displacement channels) | held-out score |",
             "|---|---|---|---|"]
    lines += [f"| {c['hidden']} | {c['parameters']} | {_fmt(c['information_criterion'])} | {_fmt(c['held_out_score'])} |"
              for c in rep["candidates"]]
    lines += ["", f"## Held-out RMSE of the kept structure fitted on the first "
              f"{100 * (1 - rep['holdout_fraction']):.0f} % (K for temperatures, um or um/m for displacements; "
              f"score {_fmt(rep['held_out_score'])}: mean RMSE / training spread)", "",
              "| channel | twin | twin before the fit | training mean | static regression | values |",
              "|---|---|---|---|---|---|"]
    for c, r in rep["held_out_rmse"].items():
        lines.append(f"| {c} | {_fmt(r['twin'])} | {_fmt(r['twin before fit'])} | {_fmt(r['training mean'])} | "
                     f"{_fmt(r['static regression'])} | {r['n']} |")
    lines += ["", "The twin written is the one fitted on the whole recording (its last 5 % out).", ""]
    lines += [f"- {n}" for n in rep["notes"]]
    return "\n".join(lines) + "\n"



def run(args) -> int:
    """Exit code: 0 written, 2 bad input (one line naming the field and value)."""
    out = pathlib.Path(args.out)
    try:
        if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
            raise DescriptionError(f"--out {args.out}: exists and is not an empty folder (--force writes into it)")
        d = load_description(args.description)
        rec = read_recording(args.recording, args.hours, args.sample_period_s)
        say = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr, flush=True))
        rep = init_twin(d, rec, out, holdout=args.holdout, max_nfev=args.max_nfev, progress=say)
    except (DescriptionError, CalibrationError, MachineSpecError, RecordingError, BagRecordingError,
            OSError, ValueError) as exc:
        print(f"thermal-comp twin init: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {rep['files']['twin']} ({rep['hidden_bodies']} hidden bodies), {out / 'report.md'}; "
          f"soft sensors for a TALC config: {', '.join(rep['soft_sensors'])}")
    return 0
