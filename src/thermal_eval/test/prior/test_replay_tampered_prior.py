"""`thermal-comp replay --prior` refuses a prior that was changed after it was written or whose
ARX models diverge (parameters x1000): exit 2, one line naming the file or the field, nothing
written; the untouched prior replays."""
import json

import pytest

from talc_model.prior.integrity import stamped
from talc_model.prior.talc import build_talc_prior, save_prior
from thermal_comp_common.recording_csv import write_recording_csv
from thermal_eval.replay.cli import main
from thermal_twin.sim.scenarios import make_timeline
from thermal_twin.sim.simulate import simulate

INPUTS = ["ambient", "ws_mwf", "c_coolant_delta"]
CFG = ["--set", f"input_names=[{', '.join(INPUTS)}]", "--set", "na_max=1", "--set", "nb_max=3",
       "--set", "nb_max_final=3"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tampered")
    recs = []
    for i, s in enumerate(["load-case-A", "load-case-D", "load-case-B"]):
        r = simulate("nmv5000", make_timeline("nmv5000", s, hours=24.0, seed=101 + i, step_s=300.0), seed=101 + i)
        recs.append(r.to_recording())
    run = simulate("nmv5000", make_timeline("nmv5000", "load-case-A", hours=6.0, seed=0, step_s=300.0), seed=0)
    write_recording_csv(tmp / "run.csv", run.time_s, run.columns())
    good = save_prior(tmp / "prior.json", build_talc_prior(recs, {"input_names": INPUTS}, nb_max=3))
    return tmp, good


def _replay(tmp, prior, capsys):
    capsys.readouterr()
    rc = main([str(tmp / "run.csv"), "--model", "talc", *CFG, "--prior", str(prior),
               "--json", str(tmp / "out.json"), "--no-progress"])
    return rc, capsys.readouterr().err.strip()


def test_scaled_or_changed_priors_are_refused(files, capsys):
    tmp, good = files
    data = json.loads(good.read_text())
    for m in data["talc_state"]["models"].values():
        m["theta"] = [v * 1000.0 for v in m["theta"]]
    scaled = tmp / "x1000.json"
    scaled.write_text(json.dumps(data))                 # the hash no longer matches
    rc, err = _replay(tmp, scaled, capsys)
    assert rc == 2 and len(err.splitlines()) == 1
    assert f"prior '{scaled}': field 'sha256' does not match the content" in err
    scaled.write_text(json.dumps(stamped(data)))        # re-hashed: the poles refuse it
    rc, err = _replay(tmp, scaled, capsys)
    assert rc == 2 and len(err.splitlines()) == 1 and "ARX pole of radius" in err
    assert not (tmp / "out.json").exists()
    rc, _ = _replay(tmp, good, capsys)                  # the untouched prior replays
    assert rc == 0 and (tmp / "out.json").is_file()
