"""rerun: our messages become the documented entities; rerun's own tools load our bags and
our .rrd files; the served web viewer shows our data in headless Chromium."""
import math
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import rerun as rr

from bags_helpers import small_recording_csv, wait_for
from thermal_comp_common.bags import msg_definitions as md
from thermal_comp_common.bags.csv_to_bag import csv_to_bag
from thermal_comp.view import browser
from thermal_comp.view.rerun_logging import (COLOURS, LayoutError, RerunLogger, load_layout,
                                        schematic_layout, split_topic)

RERUN = pathlib.Path(sys.executable).parent / "rerun"


def _env(tmp_path) -> dict:
    env = dict(os.environ)
    env["HOME"] = str(tmp_path / "home")   # rerun writes analytics config into HOME
    (tmp_path / "home").mkdir(exist_ok=True)
    return env


def _rerun(tmp_path, *args) -> subprocess.CompletedProcess:
    return subprocess.run([str(RERUN), *args], env=_env(tmp_path), capture_output=True, text=True,
                          timeout=120)


def _entities(tmp_path, rrd) -> set[str]:
    out = _rerun(tmp_path, "rrd", "print", str(rrd)).stdout
    return {line.split(" - ", 1)[1].split(" - ")[0].strip()
            for line in out.splitlines() if line.startswith("Chunk(") and " - /" in line}


def _msg(store, type_name, **fields):
    return store.types[type_name](**fields)


def _synthetic_messages():
    """One message of every type our graph publishes (through the rosbags typestore)."""
    s = md.typestore()
    T = s.types["builtin_interfaces/msg/Time"]
    H = s.types["std_msgs/msg/Header"]

    def h(t):
        return H(stamp=T(sec=int(t), nanosec=0), frame_id="")

    msgs = []
    for k in range(5):
        t = 60 * k
        msgs.append(("/cell1/errors/predicted", "thermal_comp_msgs/msg/ThermalErrors", t, _msg(
            s, "thermal_comp_msgs/msg/ThermalErrors", header=h(t), source=1, model_kind="talc",
            component_names=["E_X0C"], values=np.array([1.0 + k]), units=np.array([0], np.uint8),
            uncertainties=np.array([0.5]))))
        msgs.append(("/cell1/offsets", "thermal_comp_msgs/msg/AxisOffsets", t, _msg(
            s, "thermal_comp_msgs/msg/AxisOffsets", header=h(t), axis_names=["X"],
            commanded_offsets_um=np.array([-1.0 - k]), applied_offsets_um=np.array([-1.0 - k]),
            applied=np.array([True]), limits_hit=np.array([2 if k == 4 else 0], np.uint8),
            compensation_enabled=True)))
        msgs.append(("/cell1/model_status", "thermal_comp_msgs/msg/ModelStatus", t, _msg(
            s, "thermal_comp_msgs/msg/ModelStatus", header=h(t), model_kind="talc", phase=0 if k < 3 else 1,
            probing_cycles=k, failed_probing_cycles=0, no_good_phases=0, parameter_updates=k // 3,
            training_samples=10 * k, q_prod_pct=98.0, next_probing_due=T(sec=600, nanosec=0),
            max_uncertainty=0.5, excluded_sensor_ids=[], message="identified" if k == 3 else "")))
        msgs.append(("/cell1/machine_state", "thermal_comp_msgs/msg/MachineState", t, _msg(
            s, "thermal_comp_msgs/msg/MachineState", header=h(t), spindle_names=["main_spindle"],
            spindle_speeds_rpm=np.array([1000.0]), rotary_axis_names=["C"],
            rotary_axis_speeds_rpm=np.array([0.0]), axis_names=["X"], axis_positions=np.array([10.0]),
            coolant_on=False, coolant_temperature_degc=math.nan, door_open=False,
            drive_names=["X"], drive_powers_w=np.array([50.0]), machine_busy_probing=(k == 2))))
    msgs.append(("/cell1/errors/measured", "thermal_comp_msgs/msg/ThermalErrors", 120, _msg(
        s, "thermal_comp_msgs/msg/ThermalErrors", header=h(120), source=0, model_kind="probe_sphere",
        component_names=["E_X0C"], values=np.array([3.2]), units=np.array([0], np.uint8),
        uncertainties=np.array([0.3]))))
    msgs.append(("/cell1/sim_sync", "thermal_comp_msgs/msg/SimSync", 0, _msg(
        s, "thermal_comp_msgs/msg/SimSync", header=h(0), node_name="talc_model",
        processed_until=T(sec=0, nanosec=0))))
    return msgs


def test_every_message_type_maps_to_its_entities(tmp_path):
    rrd = tmp_path / "synthetic.rrd"
    rec = rr.RecordingStream("thermal_comp_test")
    rec.save(rrd)
    logger = RerunLogger(rec, schematic_layout(["a"]))
    for topic, type_name, t, msg in _synthetic_messages():
        logger.log(topic, type_name, msg, int(t * 1e9))
    rec.flush()
    rec.disconnect()
    assert _rerun(tmp_path, "rrd", "verify", str(rrd)).returncode == 0
    ents = _entities(tmp_path, rrd)
    for e in ("/cell1/errors/E_X0C/predicted", "/cell1/errors/E_X0C/predicted_upper_2sigma",
              "/cell1/errors/E_X0C/predicted_lower_2sigma", "/cell1/errors/E_X0C/measured",
              "/cell1/offsets/X/commanded", "/cell1/offsets/X/applied", "/cell1/model/phase",
              "/cell1/model/q_prod_pct", "/cell1/machine/spindle/main_spindle_rpm",
              "/cell1/machine/busy_probing", "/cell1/events"):
        assert e in ents, (e, sorted(ents))
    assert logger.counts["/cell1/sim_sync"] == 1
    assert not any("sim_sync" in e for e in ents)


def test_topics_split_into_namespace_and_known_name():
    assert split_topic("/cell1/errors/predicted") == ("cell1", "errors/predicted")
    assert split_topic("/temperatures") == ("", "temperatures")
    assert split_topic("/a/b/twin/sensor_readings") == ("a/b", "twin/sensor_readings")
    assert split_topic("/other") == ("", "other")


def test_layout_file_positions_and_errors(tmp_path):
    f = tmp_path / "layout.yaml"
    f.write_text("sensors:\n  ambient: {position_mm: [1000, 0, 500]}\n  spindle: {position_mm: [0, 0, 1200]}\n"
                 "  no_position: {note: x}\n")
    lay = load_layout(f)
    assert lay.positions_m == {"ambient": (1.0, 0.0, 0.5), "spindle": (0.0, 0.0, 1.2)}
    assert not lay.schematic
    f.write_text("sensors:\n  ambient: {position_mm: [1, 2]}\n")
    with pytest.raises(LayoutError, match=r"sensors.ambient.position_mm: \[1, 2\]"):
        load_layout(f)
    f.write_text("nodes: {}\n")
    with pytest.raises(LayoutError, match="'sensors' missing"):
        load_layout(f)
    with pytest.raises(LayoutError, match="No such file"):
        load_layout(tmp_path / "none.yaml")
    ring = schematic_layout(["b", "a", "c"])
    assert ring.schematic and set(ring.positions_m) == {"a", "b", "c"}


@pytest.fixture
def bag(tmp_path):
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=30), tmp_path / "bag")
    return tmp_path / "bag"


def test_rerun_itself_loads_and_decodes_our_bag(tmp_path, bag):
    mcap = bag / "bag_0.mcap"
    check = _rerun(tmp_path, "mcap", "check", str(mcap))
    assert check.returncode == 0, check.stdout + check.stderr
    out = tmp_path / "native.rrd"
    conv = _rerun(tmp_path, "mcap", "convert", str(mcap), "-o", str(out))
    assert conv.returncode == 0, conv.stderr
    printed = _rerun(tmp_path, "rrd", "print", str(out)).stdout
    for t in ("TemperatureArray", "ThermalErrors", "MachineState"):
        assert f"with 30 rows" in printed and f"thermal_comp_msgs.msg.{t}:message" in printed


def test_view_converts_a_bag_to_a_verified_rrd(tmp_path, bag):
    out = tmp_path / "view.rrd"
    p = subprocess.run([sys.executable, "-m", "thermal_comp.view.cli", str(bag), "--rrd", str(out),
                        "--no-progress"], env=_env(tmp_path), capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    assert "90 messages logged" in p.stdout
    v = _rerun(tmp_path, "rrd", "verify", str(out))
    assert v.returncode == 0, v.stdout + v.stderr
    ents = _entities(tmp_path, out)
    assert {"/temperatures/ambient", "/temperatures/c_motor", "/errors/E_X0C/ground_truth",
            "/errors/E_A0C/ground_truth", "/machine/rotary/C_rpm", "/machine/sensors"} <= ents


def test_view_rejects_bad_input(tmp_path):
    p = subprocess.run([sys.executable, "-m", "thermal_comp.view.cli", str(tmp_path / "nope"), "--rrd",
                        str(tmp_path / "x.rrd"), "--no-progress"], env=_env(tmp_path),
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "no such bag" in p.stderr and "Traceback" not in p.stderr


def _magenta_pixels(png: bytes) -> int:
    from io import BytesIO
    from PIL import Image
    a = np.asarray(Image.open(BytesIO(png)).convert("RGB")).astype(int)
    r, g, b = COLOURS["ground_truth"]
    return int(((abs(a[..., 0] - r) < 25) & (abs(a[..., 1] - g) < 30) & (abs(a[..., 2] - b) < 25)).sum())


@pytest.mark.slow
def test_served_web_viewer_shows_our_entities_in_headless_chromium(tmp_path, bag):
    if not browser.CHROMIUM.exists():
        pytest.skip(f"{browser.CHROMIUM} is missing: install Debian's 'chromium' package")
    web, grpc = browser.free_port(), browser.free_port()
    viewer = subprocess.Popen([sys.executable, "-m", "thermal_comp.view.cli", str(bag), "--serve-web",
                               "--web-port", str(web), "--grpc-port", str(grpc), "--no-progress"],
                              env=_env(tmp_path), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        line = viewer.stdout.readline()
        assert line.startswith("rerun web viewer: http://localhost:"), line
        url = line.split(": ", 1)[1].strip()
        wait_for(lambda: "messages logged" in viewer.stdout.readline(), 60, "the bag to be logged")
        shots = []
        with browser.HeadlessChromium() as chromium:
            chromium.open(url)

            def rendered():
                png = chromium.screenshot()     # None while the page is still navigating
                shots.append(png) if png else None
                return png is not None and _magenta_pixels(png) > 200

            try:
                wait_for(rendered, 300, "the ground-truth error lines in the web viewer", poll=1.0)
            finally:
                if shots:
                    (tmp_path / "web_viewer.png").write_bytes(shots[-1])
    finally:
        viewer.terminate()
        viewer.communicate(timeout=30)


@pytest.mark.slow
@pytest.mark.ros
@pytest.mark.parametrize("how", ["view_cli", "node"])
def test_live_view_logs_published_topics_to_an_rrd(tmp_path, ros_context, how):
    import rclpy
    from thermal_comp_common.runtime import node_runtime as rt
    from thermal_comp_msgs.msg import TemperatureArray, ThermalErrors
    from bags_helpers import stop
    out = tmp_path / "live.rrd"
    cmd = (["-m", "thermal_comp.view.cli", "--rrd", str(out)] if how == "view_cli" else
           ["-m", "thermal_comp.view.rerun_view_node", "--ros-args", "-p", "spawn:=false", "-p", f"rrd:={out}"])
    proc = subprocess.Popen([sys.executable, *cmd], env=_env(tmp_path), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    node = rclpy.create_node("live_source", context=ros_context)
    try:
        temps = node.create_publisher(TemperatureArray, rt.TOPIC_TEMPERATURES, rt.SENSOR_QOS)
        pred = node.create_publisher(ThermalErrors, rt.TOPIC_ERRORS_PREDICTED, rt.EVENT_QOS)
        wait_for(lambda: (temps.get_subscription_count() >= 1 and pred.get_subscription_count() >= 1)
                 or proc.poll() is not None, 30, "the live viewer to subscribe")
        assert proc.poll() is None, proc.communicate()[0]
        for k in range(5):
            t = TemperatureArray()
            t.header.stamp = rt.s_to_stamp(60.0 * k)
            t.sensor_ids, t.temperatures_degc, t.status = ["spindle"], [25.0 + k], [0]
            temps.publish(t)
            e = ThermalErrors()
            e.header.stamp = t.header.stamp
            e.source, e.model_kind = ThermalErrors.SOURCE_PREDICTED, "talc"
            e.component_names, e.values, e.units, e.uncertainties = ["E_Z0T"], [1.0 * k], [0], [0.2]
            pred.publish(e)
        # the viewer writes as it goes: wait until the last message's entities are in the file
        wait_for(lambda: out.exists() and "/errors/E_Z0T/predicted_upper_2sigma" in _entities(tmp_path, out),
                 30, "the live messages in the .rrd", poll=0.5)
        out_text = stop(proc)
    finally:
        node.destroy_node()
    assert proc.returncode == 0, out_text
    assert _rerun(tmp_path, "rrd", "verify", str(out)).returncode == 0
    ents = _entities(tmp_path, out)
    assert {"/temperatures/spindle", "/errors/E_Z0T/predicted", "/errors/E_Z0T/predicted_upper_2sigma",
            "/machine/sensors"} <= ents, sorted(ents)


def test_view_shows_a_truncated_bag_up_to_the_damage(tmp_path):
    bag = tmp_path / "bag"
    csv_to_bag(small_recording_csv(tmp_path / "rec.csv", rows=100), bag, chunk_bytes=2048)
    f = bag / "bag_0.mcap"
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    out = tmp_path / "cut.rrd"
    p = subprocess.run([sys.executable, "-m", "thermal_comp.view.cli", str(bag), "--rrd", str(out),
                        "--no-progress"], env=_env(tmp_path), capture_output=True, text=True, timeout=120)
    assert p.returncode == 3, p.stderr
    assert "bag damaged, shown up to there" in p.stderr and "stopped at byte" in p.stderr
    assert "Traceback" not in p.stderr
    assert _rerun(tmp_path, "rrd", "verify", str(out)).returncode == 0
    assert "/temperatures/ambient" in _entities(tmp_path, out)


def test_spawning_without_a_display_is_refused_with_a_hint(tmp_path, bag):
    env = _env(tmp_path)
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    p = subprocess.run([sys.executable, "-m", "thermal_comp.view.cli", str(bag), "--spawn"], env=env,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "no display" in p.stderr and "--serve-web" in p.stderr


def test_layout_comes_from_the_twin_preset_whose_sensors_match():
    from thermal_comp.view.rerun_logging import preset_layout_for, resolve_layout
    lay = preset_layout_for(["ambient", "ws_mwf", "c_coolant_delta", "c_motor_internal"])
    assert lay is not None and "nmv5000" in lay.source and "not measured" in lay.source
    assert lay.positions_m == resolve_layout("nmv5000").positions_m
    assert all(len(p) == 3 for p in lay.positions_m.values())
    assert preset_layout_for(["no_such_sensor"]) is None
    with pytest.raises(LayoutError, match="neither a file nor a twin preset"):
        resolve_layout("no-such-machine")
