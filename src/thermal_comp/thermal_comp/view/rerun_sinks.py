"""Where rerun data goes: an .rrd file, rerun's web viewer served on localhost, a spawned
native viewer - any combination, for the bag view and the live view alike. No rclpy here."""
from __future__ import annotations

import os
import pathlib
import sys
from dataclasses import dataclass

import rerun as rr

APP_ID = "thermal_comp"
#: never hang at exit on a viewer that went away
FLUSH_TIMEOUT_S = 30.0


class SinkError(ValueError):
    """The requested output cannot be opened; the message says why and what to use instead."""


@dataclass
class RerunOutput:
    recording: rr.RecordingStream
    web_url: str | None = None

    def close(self) -> None:
        self.recording.flush(timeout_sec=FLUSH_TIMEOUT_S)
        self.recording.disconnect()


def has_display() -> bool:
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY") or
                                                        os.environ.get("WAYLAND_DISPLAY"))


def new_recording(app_id: str = APP_ID) -> rr.RecordingStream:
    """A recording stream without rerun's automatic ``log_time`` (wall clock): our data is on
    ``sim_time``, health records' own stamps on ``wall_time`` (see rerun_logging)."""
    rec = rr.RecordingStream(app_id)
    rec.set_log_time_enabled(False)
    return rec


def open_output(*, rrd: str | None = None, spawn: bool = False, serve_web: bool = False,
                web_port: int = 9090, grpc_port: int = 9876, blueprint=None) -> RerunOutput:
    """A recording stream writing to every requested sink (at least one must be requested)."""
    if not (rrd or spawn or serve_web):
        raise SinkError("no rerun output: choose an .rrd file, the web viewer or a spawned viewer")
    if spawn and not has_display():
        raise SinkError("no display for the native viewer (DISPLAY / WAYLAND_DISPLAY unset); "
                        "use the web viewer (--serve-web) or an .rrd file")
    rec = new_recording(APP_ID)
    sinks = []
    server = None
    if rrd:
        pathlib.Path(rrd).parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(rrd)))
    if serve_web:
        server = rr.GrpcServerSink(bind_ip="127.0.0.1", port=grpc_port)
        sinks.append(server)
    if spawn:
        port = grpc_port + 1 if serve_web else grpc_port
        viewer = pathlib.Path(sys.executable).parent / "rerun"   # the venv's viewer, PATH or not
        try:
            rr.spawn(port=port, connect=False, recording=rec,
                     executable_path=str(viewer) if viewer.is_file() else None)
        except RuntimeError as exc:
            raise SinkError(f"cannot spawn the rerun viewer: {str(exc).splitlines()[0]}") from None
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    rec.set_sinks(*sinks, default_blueprint=blueprint)
    url = None
    if server is not None:
        rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=server.uri)
        url = f"http://localhost:{web_port}/?url={server.uri}"
    return RerunOutput(rec, url)
