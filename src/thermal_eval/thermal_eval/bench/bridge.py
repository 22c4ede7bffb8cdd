"""Benchmark ``thermal-comp bench bridge``: prediction-to-write latency over OPC UA on loopback.

The CNC emulator runs as its own process (``thermal-comp cnc-emulator``), as a CNC would;
this process plays the bridge's core path for each prediction: eq. 6.3-6.5 at the current
position, one safety-envelope step, the OPC UA write of X/Y/Z with its read-back pipelined
behind it in the same round trip. The latency of one prediction is from its arrival to the
read-back that confirms it. Measured twice:
without security and with Basic256Sha256 Sign&Encrypt plus user/password (self-signed
certificates made for the run). Figures: p50, p99, max in ms, and writes/s. A histogram
PNG goes to ``--out-dir``.

A third case, ``ros_node``, measures the whole path through the real node: this process
publishes ``errors/predicted`` and waits for the ``offsets`` message that answers it (the
node publishes it after the OPC UA read-back), with the node and the emulator in their
own processes, in lock-step mode, on an isolated ROS domain (``ROS_DOMAIN_ID`` from the
environment, else one derived from the process id; discovery limited to localhost).
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
from tqdm import tqdm

from cnc_bridge.certificates import make_certificate
from cnc_bridge.cnc_emulator import ENDPOINT_PATH, free_tcp_port
from cnc_bridge.error_transform import five_axis_offsets_um
from cnc_bridge.opcua_backend import OpcUaBackend
from cnc_bridge.opcua_config import OpcUaConfig
from cnc_bridge.safety_envelope import EnvelopeConfig, SafetyEnvelope
from thermal_comp_common.components import FIVE_AXIS_COMPONENTS


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
    rng = np.random.default_rng(0)
    env = SafetyEnvelope(EnvelopeConfig(abs_limit_um=50.0, max_rate_um_per_s=5.0, max_step_s=1.0))
    lat = np.empty(n)
    for k in tqdm(range(n), desc=f"bridge latency ({label})", unit="write", leave=False):
        errors = dict(zip(FIVE_AXIS_COMPONENTS,
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


def _measure_node(n: int) -> np.ndarray:
    """Prediction published -> answering offsets received, through the cnc_bridge node."""
    os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    # ROS-free import path: ROS only for the node measurement
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from thermal_comp_common.runtime.node_runtime import (EVENT_QOS, TOPIC_ERRORS_PREDICTED, TOPIC_OFFSETS,
                                           s_to_stamp, stamp_to_s)
    from thermal_comp_msgs.msg import AxisOffsets, ThermalErrors
    port = free_tcp_port()
    emu = _start_emulator(port, [])
    ns = f"/bench_bridge_{os.getpid()}"
    node_proc = subprocess.Popen(
        [sys.executable, "-m", "cnc_bridge.cnc_bridge_node", "--ros-args", "-r", f"__ns:={ns}",
         "-p", "backend:=opcua", "-p", f"endpoint:=opc.tcp://127.0.0.1:{port}{ENDPOINT_PATH}",
         "-p", "lockstep:=true", "-p", "max_rate_um_per_s:=5.0", "-p", "autostart:=true"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("bench_bridge_client", namespace=ns, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    got: dict[float, float] = {}
    pub = node.create_publisher(ThermalErrors, TOPIC_ERRORS_PREDICTED, EVENT_QOS)
    sub = node.create_subscription(
        AxisOffsets, TOPIC_OFFSETS,
        lambda m: got.setdefault(stamp_to_s(m.header.stamp), time.perf_counter()), EVENT_QOS)

    def spin_until(cond, timeout_s, what):
        deadline = time.monotonic() + timeout_s
        while not cond():
            if time.monotonic() > deadline:
                raise RuntimeError(f"bench bridge: timed out waiting for {what}")
            ex.spin_once(timeout_sec=0.01)
    rng = np.random.default_rng(1)
    names = list(FIVE_AXIS_COMPONENTS)
    lat = []
    try:
        spin_until(lambda: pub.get_subscription_count() > 0 and sub.get_publisher_count() > 0,
                   60, "the cnc_bridge node")
        for k in tqdm(range(n + 20), desc="bridge latency (ros_node)", unit="prediction", leave=False):
            t = 10.0 * (k + 1)
            msg = ThermalErrors(source=ThermalErrors.SOURCE_PREDICTED, model_kind="bench",
                                component_names=names, values=list(rng.normal(0.0, 5.0, 7)),
                                units=[0, 0, 0, 0, 1, 1, 1], uncertainties=[0.0] * 7)
            msg.header.stamp = s_to_stamp(t)
            t0 = time.perf_counter()
            pub.publish(msg)
            spin_until(lambda: t in got, 30, f"offsets for t={t}")
            if k >= 20:                                  # the first 20 warm up
                lat.append(got[t] - t0)
    finally:
        node.destroy_node()
        ctx.try_shutdown()
        for proc in (node_proc, emu):
            proc.send_signal(signal.SIGINT if proc is node_proc else signal.SIGTERM)
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    return np.asarray(lat)


def _figures(lat: np.ndarray) -> dict:
    ms = lat * 1e3
    return {"n": int(ms.size), "p50_ms": round(float(np.percentile(ms, 50)), 3),
            "p99_ms": round(float(np.percentile(ms, 99)), 3), "max_ms": round(float(ms.max()), 3),
            "writes_per_s": round(float(ms.size / lat.sum()), 1)}


def run(args) -> dict:
    n = 200 if getattr(args, "quick", False) else 2000
    out_dir = pathlib.Path(getattr(args, "out_dir", None) or tempfile.mkdtemp(prefix="bench_bridge_"))
    out_dir.mkdir(parents=True, exist_ok=True)
    results, samples = {}, {}
    with tempfile.TemporaryDirectory(prefix="bench_bridge_certs_") as certs:
        srv_cert, srv_key = make_certificate(pathlib.Path(certs), "cnc",
                                             "urn:thermal-comp:cnc-emulator:server", server=True)
        cli_cert, cli_key = make_certificate(pathlib.Path(certs), "bridge",
                                             "urn:thermal-comp:cnc-bridge", server=False)
        creds = pathlib.Path(certs) / "emulator_credentials.yaml"   # never on the command line
        creds.touch(mode=0o600)
        creds.write_text(f"user: cnc\npassword: pw\nprivate_key: {srv_key}\n")
        cases = {
            "none": ([], {}),
            "sign_encrypt": (["--certificate", srv_cert, "--credentials-file", str(creds),
                              "--client-trust", cli_cert, "--security", "required"],
                             dict(certificate=cli_cert, private_key=cli_key, security_required=True,
                                  user="cnc", password="pw", server_trust=(srv_cert,))),
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
        samples["ros_node"] = _measure_node(min(n, 300))
        results["ros_node"] = _figures(samples["ros_node"])
    results["cpu_count"] = os.cpu_count()
    try:
        import matplotlib  # heavy: matplotlib only when plotting
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt  # heavy: matplotlib only when plotting
        fig, ax = plt.subplots(figsize=(7, 4))
        for label, lat in samples.items():
            ax.hist(lat * 1e3, bins=60, alpha=0.6, label=f"{label}: p50 {results[label]['p50_ms']} ms, "
                                                         f"p99 {results[label]['p99_ms']} ms")
        ax.set_xlabel("prediction -> confirmed write of X/Y/Z (ros_node: prediction published -> "
                      "offsets received), ms", fontsize=8)
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
