"""Every recording we write opens on simulated time: the blueprint's time panel is on
sim_time, no row on sim_time lies outside the data's span (wall-clock stamps of /rosout and
/diagnostics go to wall_time), and rerun's automatic log_time is off."""
import os
import subprocess
import sys

import pytest

import view_helpers as vh
from thermal_comp.view.rerun_logging import TIMELINE, WALL_TIMELINE, RerunLogger
from thermal_comp.view.rerun_sinks import open_output
from thermal_comp.view.run import bag_to_rrd
from thermal_comp_common.bags import msg_definitions as md
from thermal_comp_common.bags.reader import read_bag

EPS_S = 1e-6


def _assert_on_sim_time_within(rrd, first_s, last_s, health=("/rosout/cell1/talc_model", "/diagnostics/bridge")):
    spans = vh.timeline_spans(rrd)
    assert set(spans) <= {TIMELINE, WALL_TIMELINE}, sorted(spans)        # no log_time
    outside = {e: s for e, s in spans[TIMELINE].items() if s[0] < first_s - EPS_S or s[1] > last_s + EPS_S}
    assert not outside, outside
    for e in health:
        assert e in spans[TIMELINE], sorted(spans[TIMELINE])               # the health panel has them
        lo, hi = spans[WALL_TIMELINE][e]
        assert lo >= vh.WALL0_S and hi < vh.WALL0_S + 60, (e, lo, hi)      # their own stamps, kept
    return spans
    assert vh.blueprint_timeline(rrd) == [TIMELINE]


def test_a_converted_bag_keeps_wall_clock_stamps_off_sim_time(tmp_path):
    first, last = vh.health_bag(tmp_path / "bag")
    assert bag_to_rrd(tmp_path / "bag", tmp_path / "out.rrd") == (48, None)
    _assert_on_sim_time_within(tmp_path / "out.rrd", first, last)


def test_view_rrd_cli_writes_the_same_timelines(tmp_path):
    first, last = vh.health_bag(tmp_path / "bag")
    env = dict(os.environ, HOME=str(tmp_path))
    p = subprocess.run([sys.executable, "-m", "thermal_comp.view.cli", str(tmp_path / "bag"), "--rrd",
                        str(tmp_path / "v.rrd"), "--no-progress"], env=env, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0, p.stderr
    _assert_on_sim_time_within(tmp_path / "v.rrd", first, last)


def test_message_by_message_logging_as_the_live_view_does(tmp_path):
    """The live node logs each message on arrival with its header stamp and no arrival instant:
    a health record sits at the newest data stamp logged before it."""
    first, last = vh.health_bag(tmp_path / "bag")
    store = md.typestore()
    out = open_output(rrd=str(tmp_path / "live.rrd"), blueprint=None)
    logger = RerunLogger(out.recording)
    for m in sorted(read_bag(tmp_path / "bag").messages, key=lambda m: m.log_time_ns):   # arrival order
        logger.log(m.topic, m.type, store.deserialize_cdr(m.data, m.type), m.stamp_ns)
    out.close()
    spans = vh.timeline_spans(tmp_path / "live.rrd")
    assert set(spans) == {TIMELINE, WALL_TIMELINE}
    assert all(first - EPS_S <= lo and hi <= last + EPS_S for lo, hi in spans[TIMELINE].values()), spans
    assert spans[WALL_TIMELINE]["/rosout/cell1/talc_model"][0] >= vh.WALL0_S


@pytest.mark.slow
def test_the_demo_recording_opens_on_sim_time_with_health(short_demo):
    rrd = short_demo / "demo.rrd"
    stamps = [m.stamp_ns * 1e-9 for m in read_bag(short_demo / "bag").messages
              if m.type not in ("rcl_interfaces/msg/Log", "diagnostic_msgs/msg/DiagnosticArray")]
    spans = _assert_on_sim_time_within(rrd, min(stamps), max(stamps), health=())
    assert any(e.startswith("/rosout/") for e in spans[WALL_TIMELINE]), sorted(spans[WALL_TIMELINE])
    # the bridge's status (its node names it 'bridge') is in the health panel's tree
    assert any(e.startswith("/diagnostics/bridge/") and not e.endswith("/level") for e in spans[TIMELINE]), \
        sorted(spans[TIMELINE])
