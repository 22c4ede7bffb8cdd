"""Physics simulator (digital twin) of machine cells and the mismatch finder; ROS-free
(the ``machine_sim`` node lives in ``thermal_twin.machine_sim_node``). See docs/twin.md."""
from thermal_comp_common.public_api import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(__name__, {
    "machine.schema": ["Machine", "MachineSpecError", "load_machine", "save_machine", "dump_machine"],
    "machine.presets": ["preset_names"],
    "sim.scenarios": ["Scenario", "ScenarioError", "make_timeline", "scenario_names"],
    "sim.inputs_timeline": ["InputsTimeline", "TimelineError", "timeline_from_recording"],
    "sim.simulate": ["SimulationResult", "TwinStepper", "simulate"],
    "sim.scenario_runner": ["ScenarioRunner"],
    "sim.synthetic_plant": ["SyntheticPlant", "make_plant"],
    "physics.thermal_network": ["ThermalNetwork"],
    "physics.sensor_model": ["SensorBank"],
    "physics.thermo_elastic": ["ErrorMap"],
    "machine.artefact_geometry": ["ArtefactGeometry", "GuideBushArtefact", "SphereArtefact", "TouchProbeModel"],
    "diagnose.diagnosis": ["Diagnosis", "DiagnosisError", "diagnose"],
})
