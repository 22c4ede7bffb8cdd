"""A stand-in for ``thermal-comp learn`` in the online learner's tests: it parses learn's command
line (the --current-prior it was given goes into the report) and, by ``--mode``, writes a report that adopts (copying the given prior and model
configuration into --out), one that does not, exits 2 with learn's one-line refusal, or hangs."""
import argparse
import json
import pathlib
import shutil
import sys
import time

ap = argparse.ArgumentParser()
ap.add_argument("--mode", choices=("adopt", "keep", "fail", "hang", "bad-report"), required=True)
ap.add_argument("--prior", default="")
ap.add_argument("--config", default="")
ap.add_argument("recording")
ap.add_argument("--twin", required=True)
ap.add_argument("--out", required=True)
ap.add_argument("--train-h", type=float, required=True)
ap.add_argument("--current-prior", default="")
ap.add_argument("--current-config", default="")
ap.add_argument("--allow-truncated", action="store_true")
ap.add_argument("--quiet", action="store_true")
a = ap.parse_args()
if not pathlib.Path(a.recording).is_dir():
    sys.exit(f"fake learn: no recording {a.recording}")
out = pathlib.Path(a.out)
out.mkdir(parents=True)
if a.mode == "fail":
    print("thermal-comp learn: a recording without probing results", file=sys.stderr)
    sys.exit(2)
if a.mode == "hang":
    while True:              # a learn that never ends: the learner must kill it
        time.sleep(1.0)
rmse = {"E_X0C": {"type": 2.0, "unit": 0.5}}
report = {"twin": a.twin, "tested_against": {"prior": a.current_prior, "model_config": a.current_config}, "train_h": a.train_h, "recording_h": a.train_h / 0.8, "wall_s": {"calibration": 0.1},
          "adoption": {"adopt": a.mode == "adopt", "reason": f"fake {a.mode}", "validation_probes": 4,
                       "validation_rmse": rmse},
          "files": {"unit_twin": str(out / "unit_twin.yaml")}}
if a.mode == "adopt":
    (out / "unit_twin.yaml").write_text(f"# learned from {a.twin}\n")
    report["files"] |= {"prior": str(shutil.copy(a.prior, out / "prior.json")),
                        "model_config": str(shutil.copy(a.config, out / "model_config.yaml"))}
(out / "report.json").write_text("{not json" if a.mode == "bad-report" else json.dumps(report))
