"""`thermal-comp prior --from-state` with another machine's saved characteristic-diagram model:
the command writes a CD prior a run starts from, and refuses a state of another type's channels."""
import json

from talc_model.adaptive_model import PHASE_COMPENSATION
from talc_model.cd.model import CharacteristicDiagramModel
from talc_model.prior.talc import load_prior
from talc_model.prior.dispatch import model_from_prior
from thermal_comp.prior import cli as prior_cli
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

COMPONENTS = ["E_X0C", "E_Y0C"]


def _fitted_cd_state(tmp_path):
    rec = simulate("nmv5000", make_timeline("nmv5000", "load-case-A", hours=8.0, seed=9), seed=9).to_recording()
    model = CharacteristicDiagramModel({"components": COMPONENTS, "min_calibration_s": 5 * 3600.0})
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    for k, t in enumerate(rec.time_s):
        model.update_inputs(float(t), {s: float(v[k]) for s, v in sensors.items()}, {})
        if model.probe_due(float(t)):
            model.add_measurement(float(t), {c: float(rec.columns[c][k] - rec.columns[c][0]) for c in COMPONENTS}, {})
    assert model.phase == PHASE_COMPENSATION
    path = tmp_path / "cd_state.json"
    path.write_text(json.dumps(model.to_state()))
    return path


def test_the_command_makes_a_saved_cd_model_a_prior_a_run_starts_from(tmp_path):
    out = tmp_path / "prior.json"
    assert prior_cli.main(["--machine", "nmv5000", "--from-state", str(_fitted_cd_state(tmp_path)),
                           "--out", str(out)]) == 0
    prior = load_prior(out)
    assert prior["model_kind"] == "cd" and prior["sources"] == ["persisted model state"]
    run = model_from_prior("cd", {"components": COMPONENTS}, prior)
    assert run.phase == PHASE_COMPENSATION


def test_the_command_refuses_a_cd_state_of_another_types_channels(tmp_path, capsys):
    out = tmp_path / "prior.json"
    assert prior_cli.main(["--machine", "swiss-lathe", "--from-state", str(_fitted_cd_state(tmp_path)),
                           "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "temperature channels" in err and "another machine type" in err
    assert not out.exists()
