"""The pytest plugin, seen from a pytest run of its own outside this repository: markers
registered without pyproject.toml, and under pytest-xdist every worker in its own ROS domain."""
from __future__ import annotations

import json
import os
import subprocess
import sys

from thermal_comp_common.runtime import domain_ids

PROBE = '''\
import json, os, pathlib

def test_record(ros_domain_id):
    out = pathlib.Path(os.environ["RECORD_DIR"]) / (os.environ.get("PYTEST_XDIST_WORKER", "main") + ".json")
    out.write_text(json.dumps({"id": ros_domain_id, "env": os.environ["ROS_DOMAIN_ID"],
                               "log": os.environ["ROS_LOG_DIR"],
                               "range": os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"]}))
'''


def _pytest(cwd, *args, env=None) -> subprocess.CompletedProcess:
    env = dict(os.environ if env is None else env)
    for name in ("PYTEST_ADDOPTS", "PYTEST_XDIST_WORKER", "PYTEST_XDIST_WORKER_COUNT"):
        env.pop(name, None)
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-q", *args],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=180)


def test_markers_are_registered_by_the_plugin_outside_this_repository(tmp_path):
    """colcon test may run pytest where pyproject.toml's marker list does not apply."""
    (tmp_path / "test_marks.py").write_text(
        "import pytest\n\n@pytest.mark.slow\n@pytest.mark.ros\ndef test_marked():\n    pass\n")
    assert _pytest(tmp_path, "--strict-markers", "test_marks.py").returncode == 0
    without = _pytest(tmp_path, "--strict-markers", "-p", "no:thermal_comp_testing", "test_marks.py")
    assert without.returncode != 0  # without the plugin they are unknown


def test_each_xdist_worker_claims_its_own_domain_and_log_dir(tmp_path, ros_domain_id):
    (tmp_path / "test_probe.py").write_text(PROBE)
    records = tmp_path / "records"
    records.mkdir()
    env = dict(os.environ, RECORD_DIR=str(records))
    r = _pytest(tmp_path, "-n", "2", "--dist", "each", "test_probe.py", env=env)  # every test on every worker
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    seen = {p.stem: json.loads(p.read_text()) for p in records.glob("*.json")}
    assert sorted(seen) == ["gw0", "gw1"]
    ids = [rec["id"] for rec in seen.values()]
    assert all(str(rec["id"]) == rec["env"] and rec["range"] == "LOCALHOST" for rec in seen.values())
    assert len(set(ids)) == 2 and ros_domain_id not in ids  # nor the id this session holds
    assert all(1 <= i <= 101 for i in [*ids, ros_domain_id]), ids  # ROS 2's safe range on Linux
    logs = [rec["log"] for rec in seen.values()]
    assert len(set(logs)) == 2 and os.environ["ROS_LOG_DIR"] not in logs
    assert all(f"_{worker}_" in rec["log"] for worker, rec in seen.items())


def test_claimed_ids_stay_in_the_safe_range_until_it_is_exhausted(tmp_path, monkeypatch):
    """Every id handed out by default is in 1..101; when all are held the claim says so."""
    monkeypatch.setattr(domain_ids, "LOCK_DIR", tmp_path)
    holder = subprocess.Popen(  # another process holds 100 of the ids
        [sys.executable, "-c", (
        "import pathlib, sys, time\n"
        "from thermal_comp_common.runtime import domain_ids as d\n"
        f"d.LOCK_DIR = pathlib.Path({str(tmp_path)!r})\n"
        "ids = [d.claim_domain_id() for _ in range(100)]\n"
        "print(min(ids), max(ids), len(set(ids)), flush=True)\n"
        "sys.stdin.read()\n")], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        lo, hi, n = map(int, holder.stdout.readline().split())
        assert (lo >= 1, hi <= 101, n) == (True, True, 100)
        last = domain_ids.claim_domain_id()      # the one id the child left
        assert 1 <= last <= 101
        domain_ids._held.pop().close()
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
    assert domain_ids.SAFE_DOMAIN_IDS == range(0, 102)


DDS_PROBE = '''\
import json, os, pathlib, subprocess, sys
import pytest

@pytest.mark.ros
def test_record():
    child = subprocess.run([sys.executable, "-c", "import os; print(os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE', ''))"],
                           capture_output=True, text=True, check=True)
    profile = pathlib.Path(os.environ["ROS_LOG_DIR"]) / "fastdds_test_process.xml"
    pathlib.Path(os.environ["RECORD_DIR"], "dds.json").write_text(json.dumps({
        "here": os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE", ""), "child": child.stdout.strip(),
        "profile": profile.read_text() if profile.is_file() else ""}))
'''


def test_a_ros_test_process_takes_discovery_off_in_process_delivery_and_its_children_do_not(tmp_path):
    """The test process's Fast DDS gets the profile (discovery over the transport, against an
    upstream deadlock); neither the test nor a process it starts sees the variable, and a
    profile the user names is left alone."""
    (tmp_path / "test_dds.py").write_text(DDS_PROBE)
    env = dict(os.environ, RECORD_DIR=str(tmp_path))
    env.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
    run = _pytest(tmp_path, "test_dds.py", env=env)
    assert run.returncode == 0, run.stdout + run.stderr
    seen = json.loads((tmp_path / "dds.json").read_text())
    assert seen["here"] == "" and seen["child"] == ""
    assert "<intraprocess_delivery>USER_DATA_ONLY</intraprocess_delivery>" in seen["profile"]
    user = tmp_path / "user.xml"
    user.write_text("<dds/>")
    run = _pytest(tmp_path, "test_dds.py", env=dict(env, FASTRTPS_DEFAULT_PROFILES_FILE=str(user)))
    assert run.returncode == 0, run.stdout + run.stderr
    seen = json.loads((tmp_path / "dds.json").read_text())
    assert seen["here"] == str(user) and seen["child"] == str(user) and seen["profile"] == ""
