"""A saved AGP state that started from a prior resumes with that prior (the node's state_path
path goes through model_from_state, which dispatches on the kind only)."""
import json

from talc_model.adaptive_model import model_from_state
from talc_model.agp.model import AdaptiveGaussianProcess
from talc_model.prior.agp import AgpPriorModel, agp_with_prior, build_agp_prior
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate


def test_agp_state_with_a_prior_resumes_with_it():
    recs = [simulate("swiss_lathe", make_timeline("swiss_lathe", s, hours=3.0, seed=101 + i), seed=101 + i).to_recording()
            for i, s in enumerate(["lathe-oil-steps", "lathe-door-openings"])]
    prior = build_agp_prior(recs, {"components": ["GB_X"], "max_expected_error_um": 40.0}, max_points=60)
    model = agp_with_prior({"components": ["GB_X"], "max_expected_error_um": 40.0}, prior)
    rec = recs[0]
    sensors = {c[:-2]: rec.columns[c] for c in rec.names("sensor")}
    for k in range(30):
        model.update_inputs(float(rec.time_s[k]), {s: float(v[k]) for s, v in sensors.items()}, {})
    state = json.loads(json.dumps(model.to_state()))
    for back in (model_from_state(state), AdaptiveGaussianProcess.from_state(state)):
        assert isinstance(back, AgpPriorModel) and back.prior["gps"] == prior["gps"]
        assert back.predict(float(rec.time_s[29]))[0] == model.predict(float(rec.time_s[29]))[0]
    plain = {k: v for k, v in state.items() if k not in ("prior",)}
    assert type(AdaptiveGaussianProcess.from_state(plain)) is AdaptiveGaussianProcess
