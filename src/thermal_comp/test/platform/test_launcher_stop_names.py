"""The launcher's stop: a node that ignores SIGINT is killed after the grace time and named
on the launcher's output (our nodes must never need this; test_probe_stop.py checks the one
that did). In-process Launcher; the stubborn node is a few lines of Python that ignores
SIGINT/SIGTERM and says when it is ready (the synchronisation)."""
from __future__ import annotations

import io
import threading

from thermal_comp.cell.config import load_cell
from thermal_comp.cell.launcher import Launcher

STUBBORN = '''
import signal, sys, threading
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(signal.SIGTERM, signal.SIG_IGN)
print("ready", flush=True)
threading.Event().wait()
'''


def test_stop_kills_a_node_that_ignores_sigint_and_names_it(tmp_path):
    (tmp_path / "stubborn_node_h7.py").write_text(STUBBORN)
    cell_file = tmp_path / "cell.yaml"
    cell_file.write_text(
        "cell: stopcell\n"
        "nodes:\n"
        "  - {name: stubborn, module: stubborn_node_h7, restart: false,\n"
        f"     env: {{PYTHONPATH: '{tmp_path}'}}}}\n")
    ready = threading.Event()
    out = io.StringIO()
    launcher = Launcher([load_cell(cell_file)], run_dir=tmp_path / "run", output=out, grace_s=1.0,
                        on_line=lambda label, line: ready.set() if line == "ready" else None)
    launcher.start()
    try:
        assert ready.wait(60.0), out.getvalue()
    finally:
        launcher.stop()
    text = out.getvalue()
    assert "[launch] stopcell/stubborn did not stop within 1 s: SIGKILL" in text, text
    (mp,) = launcher.processes
    assert mp.popen.returncode == -9 and not mp.running()
