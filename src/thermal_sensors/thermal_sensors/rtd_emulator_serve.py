"""The work of ``thermal-comp rtd-emulator`` (:mod:`thermal_sensors.rtd_emulator_cli` parses the
arguments): serve the Modbus RTD modules of a sensor YAML with the rows of a recording CSV or with
the running twin's readings (an rclpy node)."""
from __future__ import annotations

import argparse
import signal
import sys
import threading

from tqdm import tqdm

from thermal_comp_common.runtime.node_runtime import run_node
from thermal_comp_common.recording_csv import RecordingError, read_recording_csv
from thermal_sensors.rtd_emulator import RtdEmulator, play_recording
from thermal_sensors.rtd_twin_feed_node import RtdTwinFeed
from thermal_sensors.sensor_config import (SensorConfig, SensorConfigError, load_sensor_config,
                                           require_modbus, resolve_sensor_config)


def run(args: argparse.Namespace, ros_args: list[str]) -> int:
    """Serve as the parsed arguments say; the exit code (0 served, 1 an endpoint cannot be opened,
    2 bad configuration or recording)."""
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
