"""A short demo run shared by the slow view tests (its bag and demo.rrd)."""
import os
import pathlib
import subprocess
import sys

import pytest


@pytest.fixture(scope="session")
def short_demo(tmp_path_factory) -> pathlib.Path:
    out = tmp_path_factory.mktemp("demo")
    env = dict(os.environ, HOME=str(out / "home"))
    p = subprocess.run([sys.executable, "-m", "thermal_comp.cli", "demo", "--hours", "6", "--view", "rrd",
                        "--cnc", "twin", "--no-prior", "--no-progress", "--seed", "3", "--out", str(out)],
                       env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert (out / "demo.rrd").is_file() and (out / "bag").is_dir()
    return out
