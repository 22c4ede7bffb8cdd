"""Look at a served rerun web viewer the way a user does: headless Chromium (Debian's
``chromium``) driven over the DevTools protocol, screenshots as PNG bytes. Used by the browser
tests and ``thermal-comp bench view``; no rclpy here."""
from __future__ import annotations

import base64
import json
import os
import pathlib
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from dataclasses import dataclass
from typing import Callable

import websocket

from thermal_comp.view.screenshot import LayoutNotFound, error_plots

CHROMIUM = pathlib.Path("/usr/bin/chromium")
WINDOW = (1600, 1000)


class BrowserError(RuntimeError):
    """Chromium is missing, did not start or did not answer; the message says which."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(cond: Callable[[], object], timeout_s: float, what: str, poll_s: float = 0.2):
    """``cond()``'s first truthy value, or BrowserError naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(poll_s)
    raise BrowserError(f"timed out after {timeout_s:.0f} s waiting for {what}")


class HeadlessChromium:
    """One headless Chromium with a throw-away profile; ``with`` closes it and removes the profile."""

    def __init__(self, window: tuple[int, int] = WINDOW, executable: pathlib.Path = CHROMIUM):
        if not executable.exists():
            raise BrowserError(f"{executable} is missing: install Debian's 'chromium' package "
                               "(./setup.sh --with-browser)")
        self.profile = pathlib.Path(tempfile.mkdtemp(prefix="thermal_comp_chromium_"))
        self.proc = subprocess.Popen(
            [str(executable), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
             "--no-first-run", "--disable-background-networking", "--disable-component-update",
             "--disable-sync", f"--user-data-dir={self.profile}", "--remote-debugging-port=0",
             f"--window-size={window[0]},{window[1]}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env={**os.environ, "HOME": str(self.profile)})
        self._ids = iter(range(1, 10**9))
        self.ws = None
        try:
            port_file = self.profile / "DevToolsActivePort"
            wait_until(lambda: port_file.exists() and port_file.read_text().strip(), 30,
                       "Chromium's DevTools port")
            port = int(port_file.read_text().split()[0])
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                pages = [p for p in json.load(r) if p.get("type") == "page"]
            self.ws = websocket.create_connection(pages[0]["webSocketDebuggerUrl"], timeout=60)
            self.call("Page.enable")
        except Exception:
            self.close()
            raise

    def call(self, method: str, **params) -> dict:
        """One DevTools command; its reply (``result`` or ``error``)."""
        i = next(self._ids)
        self.ws.send(json.dumps({"id": i, "method": method, "params": params}))
        while True:
            reply = json.loads(self.ws.recv())
            if reply.get("id") == i:
                return reply

    def open(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def screenshot(self) -> bytes | None:
        """PNG bytes of the page, or None while it cannot be captured (still navigating)."""
        reply = self.call("Page.captureScreenshot", format="png")
        return base64.b64decode(reply["result"]["data"]) if "result" in reply else None

    def close(self) -> None:
        if self.ws is not None:
            self.ws.close()
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> "HeadlessChromium":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class PlotCheck:
    """What the browser showed: error plots holding data of those expected, how long after the
    page was opened they first all did (None: not within the timeout), whether the page then
    settled (two screenshots in a row alike: the viewer has drawn all it received), and the
    last screenshot."""
    plots: int
    with_data: int
    seconds_to_data: float | None
    png: bytes | None
    note: str = ""
    settled: bool = False


def _read(png: bytes, n_plots: int) -> tuple[int, str, bytes]:
    """(plots with data, a note with each plot's figures, the screen's drawn content)."""
    try:
        cells = error_plots(png, n_plots)[:n_plots]
    except LayoutNotFound as exc:
        return 0, str(exc), b""
    note = "data pixels (share of width): " + ", ".join(f"{c.data_pixels} ({c.width_share:.2f})" for c in cells)
    return sum(c.has_data for c in cells), note, note.encode()


def check_error_plots(url: str, n_plots: int, timeout_s: float = 90.0, poll_s: float = 1.0,
                      settle_s: float = 60.0) -> PlotCheck:
    """Open ``url`` (a served web viewer) in headless Chromium and take a screenshot every
    ``poll_s`` until each of the ``n_plots`` error plots shows data or ``timeout_s`` passes;
    then until two screenshots in a row read alike (the page settled) for up to ``settle_s``."""
    best = PlotCheck(n_plots, 0, None, None, "no screenshot")
    with HeadlessChromium() as browser:
        browser.open(url)
        t0 = time.monotonic()
        last = None
        while time.monotonic() - t0 < timeout_s + (settle_s if best.seconds_to_data is not None else 0):
            png = browser.screenshot()
            if png is not None:
                shown, note, seen = _read(png, n_plots)
                if best.seconds_to_data is None and (best.png is None or shown >= best.with_data):
                    best = PlotCheck(n_plots, shown, None, png, note)
                if shown == n_plots and best.seconds_to_data is None:
                    best.seconds_to_data = round(time.monotonic() - t0, 1)
                if best.seconds_to_data is not None:
                    best.with_data, best.png, best.note = shown, png, note   # the latest state counts
                    if seen == last:
                        best.settled = True
                        return best
                last = seen
            time.sleep(poll_s)
    return best


def viewer_url(web_port: int, grpc_port: int) -> str:
    return f"http://localhost:{web_port}/?url=rerun%2Bhttp://127.0.0.1:{grpc_port}/proxy"


def serve_rrd(rrd: str | os.PathLike, web_port: int, grpc_port: int, env: dict | None = None) -> subprocess.Popen:
    """rerun's own viewer server (the venv's ``rerun --serve-web``) on an .rrd file, as a user
    opens a recording; returns once the web page answers (the caller terminates the process)."""
    exe = pathlib.Path(sys.executable).parent / "rerun"
    # own session: the venv's 'rerun' is a wrapper whose viewer binary is a child; stop_server
    # ends both
    proc = subprocess.Popen([str(exe if exe.is_file() else "rerun"), "--serve-web", "--web-viewer-port",
                             str(web_port), "--port", str(grpc_port), str(rrd)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                            start_new_session=True)

    def up() -> bool:
        if proc.poll() is not None:
            raise BrowserError(f"rerun --serve-web {rrd} exited with {proc.returncode}")
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{web_port}/", timeout=2):
                return True
        except OSError:
            return False
    try:
        wait_until(up, 60, "rerun's web viewer server")
    except Exception:
        stop_server(proc)
        raise
    return proc


def stop_server(proc: subprocess.Popen, timeout_s: float = 30.0) -> None:
    """End a server from :func:`serve_rrd` and its children (its process group)."""
    for sig, wait_s in ((signal.SIGTERM, timeout_s), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout=wait_s)
            break
        except subprocess.TimeoutExpired:
            continue
    try:
        os.killpg(proc.pid, signal.SIGKILL)     # a child still left in the group
    except ProcessLookupError:
        pass
