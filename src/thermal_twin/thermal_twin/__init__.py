"""Physics simulator (digital twin) of machine cells and the mismatch finder; ROS-free
(the ``machine_sim`` node lives in ``thermal_twin.machine_sim_node``). See docs/twin.md."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "machine_schema": ["Machine", "MachineSpecError", "load_machine", "save_machine", "dump_machine"],
    "presets": ["preset_names"],
    "scenarios": ["Scenario", "ScenarioError", "make_timeline", "scenario_names"],
    "inputs_timeline": ["InputsTimeline", "TimelineError", "timeline_from_recording"],
    "simulate": ["SimulationResult", "TwinStepper", "simulate"],
    "scenario_runner": ["ScenarioRunner"],
    "thermal_network": ["ThermalNetwork"],
    "sensor_model": ["SensorBank"],
    "thermo_elastic": ["ErrorMap"],
    "artefact_geometry": ["ArtefactGeometry", "GuideBushArtefact", "SphereArtefact", "TouchProbeModel"],
    "mismatch_diagnosis": ["Diagnosis", "DiagnosisError", "diagnose"],
})
