"""Benchmark ``thermal-comp bench bridge``: prediction-to-write latency over OPC UA on loopback.

The CNC emulator runs as its own process (``thermal-comp cnc-emulator``), as a CNC would;
this process plays the bridge's core path for each prediction: eq. 6.3-6.5 at the current
position, one safety-envelope step, the OPC UA write of X/Y/Z and its read-back. The
latency of one prediction is from its arrival to the confirmed read-back. Measured twice:
without security and with Basic256Sha256 Sign&Encrypt plus user/password (self-signed
certificates made for the run). Figures: p50, p99, max in ms, and writes/s. A histogram
PNG goes to ``--out-dir``.
"""
from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

from .cnc_emulator import ENDPOINT_PATH, free_tcp_port
from .error_transform import five_axis_offsets_um
from .safety_envelope import EnvelopeConfig, SafetyEnvelope


def _start_emulator(port: int, extra: list[str]) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "cnc_bridge.cnc_emulator", "--port", str(port),
                             *extra], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            start_new_session=True)
    line = proc.stdout.readline()
    if "listening on" not in line:
        proc.kill()
        raise RuntimeError(f"cnc-emulator did not start: {line!r}")
    return proc


def _measure(backend, n: int, label: str) -> np.ndarray:
    from tqdm import tqdm
    rng = np.random.default_rng(0)
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=50.0, max_rate_um_per_s=5.0, max_step_s=1.0))
    lat = np.empty(n)
    for k in tqdm(range(n), desc=f"bridge latency ({label})", unit="write", leave=False):
        errors = dict(zip(("E_X0C", "E_Y0C", "E_Z0T", "E_R0T", "E_A0C", "E_B0C", "E_C0C"),
                          rng.normal(0.0, 5.0, 7)))
        pos = rng.uniform(-300.0, 300.0, 3)
        t0 = time.perf_counter()                       # the prediction arrives
        commanded = five_axis_offsets_um(errors, *pos, b_deg=float(rng.uniform(-90, 90)))
        decisions = env.step(0.1 * k, commanded, fresh=True)
        back = backend.write_offsets({d.axis: d.applied_um for d in decisions})
        for d in decisions:
            env.confirm(d.axis, back[d.axis])
        lat[k] = time.perf_counter() - t0              # confirmed by read-back
        if any(v is None for v in back.values()):
            raise RuntimeError(f"write {k} not confirmed: {backend.last_error}")
    return lat


def _figures(lat: np.ndarray) -> dict:
    ms = lat * 1e3
    return {"n": int(ms.size), "p50_ms": round(float(np.percentile(ms, 50)), 3),
            "p99_ms": round(float(np.percentile(ms, 99)), 3), "max_ms": round(float(ms.max()), 3),
            "writes_per_s": round(float(ms.size / lat.sum()), 1)}


def run(args) -> dict:
    from .certificates import make_certificate
    from .opcua_backend import OpcUaBackend, OpcUaConfig
    n = 200 if getattr(args, "quick", False) else 2000
    out_dir = pathlib.Path(getattr(args, "out_dir", None) or tempfile.mkdtemp(prefix="bench_bridge_"))
    out_dir.mkdir(parents=True, exist_ok=True)
    results, samples = {}, {}
    with tempfile.TemporaryDirectory(prefix="bench_bridge_certs_") as certs:
        srv_cert, srv_key = make_certificate(pathlib.Path(certs), "cnc",
                                             "urn:thermal-comp:cnc-emulator:server", server=True)
        cli_cert, cli_key = make_certificate(pathlib.Path(certs), "bridge",
                                             "urn:thermal-comp:cnc-bridge", server=False)
        cases = {
            "none": ([], {}),
            "sign_encrypt": (["--certificate", srv_cert, "--private-key", srv_key,
                              "--security", "required", "--user", "cnc", "--password", "pw"],
                             dict(certificate=cli_cert, private_key=cli_key, security_required=True,
                                  user="cnc", password="pw")),
        }
        for label, (emu_args, client_kw) in cases.items():
            port = free_tcp_port()
            proc = _start_emulator(port, emu_args)
            backend = OpcUaBackend(OpcUaConfig(endpoint=f"opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}",
                                               **client_kw))
            try:
                if not backend.wait_connected(30.0):
                    raise RuntimeError(f"no connection ({label}): {backend.last_error}")
                _measure(backend, min(50, n), label)           # warm-up, not counted
                samples[label] = _measure(backend, n, label)
                results[label] = _figures(samples[label])
            finally:
                backend.close()
                proc.send_signal(signal.SIGTERM)
                proc.wait(timeout=15)
    results["cpu_count"] = os.cpu_count()
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(7, 4))
        for label, lat in samples.items():
            ax.hist(lat * 1e3, bins=60, alpha=0.6, label=f"{label}: p50 {results[label]['p50_ms']} ms, "
                                                         f"p99 {results[label]['p99_ms']} ms")
        ax.set_xlabel("prediction -> confirmed write (write X/Y/Z + read-back), ms")
        ax.set_ylabel("predictions")
        ax.set_yscale("log")
        ax.set_title("cnc_bridge latency over OPC UA, loopback")
        ax.legend()
        fig.tight_layout()
        png = out_dir / "bridge_latency.png"
        fig.savefig(png, dpi=110)
        plt.close(fig)
        results["plot"] = str(png)
    except ImportError:
        pass
    print(results)
    return results
