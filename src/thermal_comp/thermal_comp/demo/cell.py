"""The demo's machine cell: what each built-in machine runs and the cell document of its graph.

The document has the format of ``thermal-comp launch`` cell files, so the demo runs the same
nodes, parameters and restart policy a real cell would (fault injection reuses it).
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass
from typing import Any

import talc_model
from thermal_comp_common.components import FIVE_AXIS_COMPONENTS
from thermal_twin.machine.instance import instance_label, write_instance
from thermal_twin.sim.scenarios import SCENARIOS, make_timeline

#: What each built-in machine runs.
MACHINES: dict[str, dict[str, Any]] = {
    "nmv5000": {"scenario": "talc-178h-dry", "model_kind": "talc", "artefact": "sphere",
                "sensor_config": "nmv5000", "step_s": 300.0, "compensation_mode": "kinematic",
                "model_config": "talc_nmv5000.yaml",
                "offset_axes": list(FIVE_AXIS_COMPONENTS),
                # the bridge's absolute offset limit for this type: above its own thermal error
                # (thesis Table 6.5: uncompensated P99 of E_Z0T 27.5 um on the real machine; unit #1
                # reaches 35 um in talc-178h-dry), so the bound catches a runaway model without
                # clamping legitimate compensation (the bridge's default, 30 um, did: 81 steps)
                "abs_limit_um": 50.0},
    "swiss-lathe": {"scenario": "lathe-random-speed", "model_kind": "agp", "artefact": "guide_bush",
                    "sensor_config": "swiss_lathe", "step_s": 60.0, "tool_position": "GB",
                    "offset_axes": ["GB_X"]},
}


#: ``DemoConfig.prior``: the machine type's prior, from the cache or built on a miss
BUILD_PRIOR = "build"
#: ``DemoConfig.prior``: the type's prior where one applies, else none (the run says why)
DEFAULT_PRIOR = "default"


class DemoError(RuntimeError):
    """The demo could not run; the message says which part failed."""


@dataclass
class DemoConfig:
    machine: str = "nmv5000"
    scenario: str | None = None
    hours: float | None = None
    seed: int = 0
    step_s: float | None = None
    out_dir: pathlib.Path = pathlib.Path("demo_out")
    view: str = "auto"                 # auto | live | rrd | none
    cnc: str = "opcua"                 # opcua | twin
    progress: bool = True
    wall_timeout_s: float = 3600.0
    #: restart policy of every node (cell-file ``restart`` mapping); None = no restarts
    restart: dict[str, Any] | None = None
    #: the plant: unit ``unit`` of the machine type (thermal_twin.machine.instance); None = nominal
    unit: int | None = None
    #: prior file (thermal-comp prior: TALC or AGP, the machine's model) the model starts from, BUILD_PRIOR or
    #: DEFAULT_PRIOR (demo_run.resolve_prior turns them into a file or None); None = the thesis's start
    prior: str | None = None
    #: at most this many simulated s per wall s (machine_sim's lock-step ceiling); 0 = as fast as possible
    real_time_factor: float = 0.0
    #: the plant from a machine YAML file of the type (replaces ``unit``); None = ``unit``
    plant: str | None = None
    #: the online learner in the graph: learn from the recording every this many simulated hours; 0 = none
    learn_every_h: float = 0.0


def scenario_hours(machine: str, scenario: str, hours: float | None) -> float:
    make_timeline(machine, scenario, hours=hours or None, step_s=3600.0)  # validates the pair
    return float(hours) if hours else float(SCENARIOS[scenario].hours)


def plant_machine(cfg: DemoConfig, out: pathlib.Path) -> str:
    """The machine the twin simulates: ``cfg.plant``, the preset, or unit ``cfg.unit`` of it written to ``out``."""
    if cfg.plant:
        return str(pathlib.Path(cfg.plant).resolve())
    if cfg.unit is None:
        return cfg.machine
    return str(write_instance(out / f"machine_unit{cfg.unit}.yaml", cfg.machine, cfg.unit))


def plant_label(cfg: DemoConfig) -> str:
    """Which machine the demo ran: ``nmv5000 unit #1``, ``nmv5000 (nominal)`` or the plant file's name."""
    if cfg.plant:
        return f"{cfg.machine} plant {pathlib.Path(cfg.plant).name}"
    return instance_label(cfg.machine, cfg.unit) if cfg.unit is not None else f"{cfg.machine} (nominal)"


def _model_parameters(cfg: DemoConfig, out: pathlib.Path) -> dict[str, Any]:
    m = MACHINES[cfg.machine]
    params: dict[str, Any] = {"model_kind": m["model_kind"], "state_path": str(out / "model_state.json"),
                              "lockstep_participant": True, "artefact": m["artefact"]}
    if m.get("tool_position"):
        params["tool_position"] = m["tool_position"]
    if cfg.prior:
        params["prior_path"] = str(pathlib.Path(cfg.prior).resolve())
    if m.get("model_config"):   # shipped with talc_model: the thesis's parameter set for this machine
        params["model_config"] = str(pathlib.Path(talc_model.__file__).with_name("config") / m["model_config"])
    return params


def _bridge_parameters(cfg: DemoConfig, out: pathlib.Path, endpoint: str | None) -> dict[str, Any]:
    m = MACHINES[cfg.machine]
    bridge: dict[str, Any] = {"lockstep": True, "audit_log_path": str(out / "cnc_audit.log"),
                              "backend": cfg.cnc}
    if m.get("offset_axes"):
        bridge["offset_axes"] = m["offset_axes"]
    if m.get("compensation_mode"):
        bridge["compensation_mode"] = m["compensation_mode"]
    if m.get("abs_limit_um"):
        bridge["abs_limit_um"] = float(m["abs_limit_um"])
    if endpoint:
        bridge["endpoint"] = endpoint
    return bridge


AUDIT = "learn_audit.jsonl"
LEARN_DIR = "learn"
#: the demo's lock-step ceiling with a learner when none is given (simulated s per wall s): the
#: graph otherwise runs 15000-20000 x real time and a learning of 10-40 s wall would span 50-200
#: simulated hours; at 1200 x it spans a few hours, as minutes of learning do in a real cell
LEARNING_REAL_TIME_FACTOR = 1200.0
#: wall-clock limit of one learn subprocess in the demo
LEARN_TIMEOUT_S = 600.0


def learner_node(cfg: DemoConfig, out: pathlib.Path) -> dict[str, Any]:
    """The learner node of the demo cell: learns from the recorder's bag on the type's twin. It
    reaches ``thermal-comp learn`` (package thermal_eval, above this one) only as a command."""
    params = {"recording": str(out / "bag"), "twin": cfg.machine, "work_dir": str(out / LEARN_DIR),
              "learn_every_h": float(cfg.learn_every_h), "learn_timeout_s": LEARN_TIMEOUT_S,
              "audit_path": str(out / AUDIT)}
    if cfg.prior:
        params["prior_path"] = str(pathlib.Path(cfg.prior).resolve())
    return {"name": "learner", "module": "talc_model.learner_node", "parameters": params}


def build_cell(cfg: DemoConfig, domain_id: int, endpoint: str | None, live_view: bool) -> dict:
    """The cell document of the demo graph (the same format as `thermal-comp launch`)."""
    m = MACHINES[cfg.machine]
    out = cfg.out_dir.resolve()
    step = cfg.step_s or m["step_s"]
    participants = ["sensors", "model", "bridge", "recorder"]   # the recorder acks what it wrote
    plant = plant_machine(cfg, out)
    nodes = [
        {"name": "machine_sim", "module": "thermal_twin.machine_sim_node",
         "parameters": {"machine": plant, "scenario": cfg.scenario, "seed": cfg.seed,
                        "hours": float(cfg.hours or 0.0), "step_s": float(step),
                        "lockstep_participants": participants, "shutdown_when_done": True,
                        # the first instant waits until the recorder (a participant) subscribes
                        "wait_for_subscribers": ["recorder"],
                        "state_path": str(out / "twin_state.pkl"),
                        "real_time_factor": float(cfg.real_time_factor)}},
        {"name": "sensors", "module": "thermal_sensors.temperature_publisher_node",
         "parameters": {"source": "twin", "sensor_config": m["sensor_config"], "lockstep_participant": True}},
        {"name": "probe_cycle", "module": "probe_cycle.probe_cycle_node", "parameters": {"backend": "twin"}},
        {"name": "model", "module": "talc_model.talc_model_node", "parameters": _model_parameters(cfg, out)},
        {"name": "bridge", "module": "cnc_bridge.cnc_bridge_node",
         "parameters": _bridge_parameters(cfg, out, endpoint)},
        {"name": "frames", "module": "thermal_comp.frames.static_frames_node",     # static TF (REP 105)
         "parameters": {"machine": plant}},
        {"name": "recorder", "module": "thermal_comp.bags.recorder_node",
         "parameters": {"output": str(out / "bag"), "lockstep_participant": True, "health": True,
                        # every participant publishes from the first instant: one lost before the
                        # recorder matched its publisher is waited for (machine_sim re-sends t_0)
                        "expect_from_start": ["temperatures", "errors/predicted", "offsets",
                                              "errors/ground_truth"]}},
    ]
    if cfg.learn_every_h > 0:
        nodes.append(learner_node(cfg, out))
        model = next(n for n in nodes if n["name"] == "model")
        model["parameters"].update(online_learning=True, audit_path=str(out / AUDIT))
    if live_view:
        nodes.append({"name": "viewer", "module": "thermal_comp.view.rerun_view_node", "parameters": {}})
    cell = {"cell": "demo", "domain_id": domain_id, "use_sim_time": True, "nodes": nodes}
    if cfg.restart is not None:
        cell["restart"] = dict(cfg.restart)
    return cell
