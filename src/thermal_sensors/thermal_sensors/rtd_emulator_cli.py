"""``thermal-comp rtd-emulator``: serve the Modbus RTD modules of a sensor YAML with the rows
of a recording CSV, or with the running twin's readings (``--twin``, an rclpy node here).
See docs/sensors.md ("The RTD emulator")."""
from __future__ import annotations

import argparse
import math
import signal
import sys
import threading

from tqdm import tqdm

from thermal_comp_common.node_runtime import run_node
from thermal_comp_common.recording_csv import RecordingError, read_recording_csv
from thermal_sensors.rtd_emulator import RtdEmulator, play_recording
from thermal_sensors.rtd_twin_feed_node import RtdTwinFeed
from thermal_sensors.sensor_config import (SensorConfig, SensorConfigError, load_sensor_config,
                                           require_modbus, resolve_sensor_config)


def _started(config: SensorConfig) -> RtdEmulator | None:
    """A started emulator, or None (reason printed) if an endpoint cannot be opened."""
    emu = RtdEmulator(config)
    try:
        emu.start()
    except RuntimeError as exc:
        print(f"rtd-emulator: {exc}", file=sys.stderr)
        return None
    return emu


def _serve_twin(config: SensorConfig, ros_args: list[str]) -> int:
    """Serve the twin's live readings until Ctrl-C / SIGTERM (an rclpy node in this process)."""
    emu = _started(config)
    if emu is None:
        return 1

    def feed(context):
        return RtdTwinFeed(context=context, emulator=emu)
    feed.__name__ = "rtd-emulator"
    try:
        return run_node(feed, ["rtd-emulator"] + ros_args)
    finally:
        emu.stop()


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="thermal-comp rtd-emulator",
        description="Serve the Modbus RTD modules of a sensor YAML (register map, unit ids, "
                    "ports) with temperatures from a recording CSV or from the running twin, "
                    "for bench setups and tests.")
    p.add_argument("--config", required=True,
                   help="sensor YAML with sensors[].modbus and modbus.modules, or a shipped one by name "
                        "(rtd_bench)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--csv", help="recording CSV (shared format); column = channel + '_c'")
    src.add_argument("--twin", action="store_true",
                     help="serve machine_sim's live twin/sensor_readings (ROS; matched by channel); "
                          "ROS arguments may follow after --ros-args")
    p.add_argument("--speed", type=float, default=1.0,
                   help="playback speed: recording seconds per wall second (default 1)")
    p.add_argument("--loop", action="store_true", help="start over at the end of the recording")
    p.add_argument("--hold", action="store_true",
                   help="after the last row keep serving it until Ctrl-C (a stuck value: clients "
                        "will flag it stale) instead of exiting")
    return p


def main(argv: list[str] | None = None) -> int:
    """Emulate Pt100/RTD Modbus modules on loopback, serving temperatures from a CSV or the twin."""
    p = _parser()
    args, ros_args = p.parse_known_args(argv)
    if ros_args and not (args.twin and ros_args[0] == "--ros-args"):
        p.error(f"unrecognized arguments: {' '.join(ros_args)}")
    if not (args.speed > 0 and math.isfinite(args.speed)):
        p.error(f"--speed: {args.speed!r} must be > 0")
    try:
        config = load_sensor_config(resolve_sensor_config(args.config))
        require_modbus(config)
        recording = None if args.twin else read_recording_csv(args.csv)
    except (SensorConfigError, RecordingError) as exc:
        print(f"rtd-emulator: {exc}", file=sys.stderr)
        return 2
    if args.twin:
        return _serve_twin(config, ros_args)
    for w in recording.warnings:
        print(f"rtd-emulator: warning: {w}", file=sys.stderr)
    return _serve_csv(config, recording, args)


def _serve_csv(config: SensorConfig, recording, args) -> int:
    """Serve the recording's rows at their times, then exit (or hold / loop as asked)."""
    emu = _started(config)
    if emu is None:
        return 1
    for m in config.modules:
        where = m.serial_port if m.transport == "rtu" else f"{m.host}:{m.port}"
        print(f"rtd-emulator: module {m.name} ({m.transport}, unit {m.unit_id}) on {where}", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda signum, frame: stop.set())  # polite stop: close endpoints
    bar = tqdm(total=len(recording), unit="row", desc="serving", disable=not sys.stderr.isatty())

    def progress(k, n):
        bar.n = k + 1
        bar.refresh()
    try:
        served = play_recording(emu, recording, args.speed, args.loop, stop, progress)
        bar.close()
        print(f"rtd-emulator: served {served} rows", flush=True)
        if args.hold and not stop.is_set():
            print("rtd-emulator: holding the last row (Ctrl-C to stop)", flush=True)
            while not stop.wait(3600):
                pass
    except KeyError as exc:
        print(f"rtd-emulator: {exc.args[0]}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    finally:
        bar.close()
        emu.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
