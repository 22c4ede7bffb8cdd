"""Benchmark ``view``: what a user sees of a demo recording in rerun's web viewer, and how fast
a bag becomes an .rrd.

A short demo (``thermal-comp demo``, twin CNC, no prior, fixed seed) is run; its ``demo.rrd``
is served by rerun's own viewer server and its bag by ``thermal-comp view BAG --serve-web``,
each opened in headless Chromium. Figures: the share of error plots whose plot area shows data
across at least half its width (``thermal_comp.view.screenshot``) once the page has settled
(two screenshots alike), and the seconds from opening the page until all first did.
Conversion throughput: ``bag_to_rrd`` of the demo's bag and of the ``bags`` suite's synthetic
5-axis stream, median of three runs, per wall and per CPU second. What each figure means is in
docs/bags.md ("Views").
"""
from __future__ import annotations

import os
import pathlib
import shutil
import statistics
import subprocess
import sys
import time

from thermal_comp.view import browser
from thermal_comp.view.run import bag_to_rrd, error_components
from thermal_comp_common.bags.reader import read_bag
from thermal_comp_common.bags.writer import BagWriter, TopicInfo
from thermal_eval.bench.bags import synthetic_stream

SEED = 3
RUNS = 3


def _demo(out: pathlib.Path, hours: float) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "thermal_comp.cli", "demo", "--hours", str(hours), "--view", "rrd",
                        "--cnc", "twin", "--no-prior", "--no-progress", "--seed", str(SEED), "--out", str(out)],
                       capture_output=True, text=True, timeout=1800, env=dict(os.environ, HOME=str(out.parent)))
    if p.returncode != 0:
        raise RuntimeError(f"demo failed ({p.returncode}): {(p.stderr or p.stdout)[-500:]}")
    return {"simulated_h": hours, "wall_s": round(time.perf_counter() - t0, 1)}


def _throughput(bag: pathlib.Path, folder: pathlib.Path) -> dict:
    """Messages per wall second and per CPU second of this process (all its threads: rerun
    encodes and writes in its own), median of RUNS; the CPU figure is the one that other work
    on a shared machine hardly moves."""
    wall, cpu, n = [], [], 0
    for k in range(RUNS):
        rrd = folder / f"conv_{k}.rrd"
        rrd.unlink(missing_ok=True)
        t0, c0 = time.perf_counter(), time.process_time()
        n, _ = bag_to_rrd(bag, rrd)
        wall.append(n / (time.perf_counter() - t0))
        cpu.append(n / (time.process_time() - c0))
        rrd.unlink()
    return {"messages": n, "messages_per_s_median": round(statistics.median(wall)),
            "messages_per_cpu_s_median": round(statistics.median(cpu)),
            "messages_per_s_runs": [round(r) for r in wall]}


def _synthetic_bag(folder: pathlib.Path, instants: int) -> pathlib.Path:
    stream = synthetic_stream(instants, seed=SEED)
    shutil.rmtree(folder, ignore_errors=True)
    topics = {topic: type_name for topic, type_name, _, _ in stream}
    with BagWriter(folder, [TopicInfo(n, t) for n, t in topics.items()]) as w:
        for topic, _, t_ns, data in stream:
            w.write(topic, t_ns, data)
    return folder


def _figure(check: browser.PlotCheck) -> dict:
    return {"error_plots_with_data": f"{check.with_data}/{check.plots}", "page_settled": check.settled,
            "seconds_to_data": check.seconds_to_data, "detail": check.note}


def _browser_rrd(rrd: pathlib.Path, n_plots: int, shots: pathlib.Path) -> dict:
    web, grpc = browser.free_port(), browser.free_port()
    server = browser.serve_rrd(rrd, web, grpc, env=dict(os.environ, HOME=str(shots)))
    try:
        check = browser.check_error_plots(browser.viewer_url(web, grpc), n_plots, timeout_s=300)
    finally:
        browser.stop_server(server)
    if check.png:
        (shots / "demo_rrd.png").write_bytes(check.png)
    return _figure(check)


def _browser_serve_web(bag: pathlib.Path, n_plots: int, shots: pathlib.Path, run: int) -> dict:
    web, grpc = browser.free_port(), browser.free_port()
    viewer = subprocess.Popen([sys.executable, "-m", "thermal_comp.view.cli", str(bag), "--serve-web",
                               "--web-port", str(web), "--grpc-port", str(grpc), "--no-progress"],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              env=dict(os.environ, HOME=str(shots)))
    try:
        line = viewer.stdout.readline()
        if not line.startswith("rerun web viewer: "):
            raise RuntimeError(f"thermal-comp view --serve-web printed {line!r}")
        check = browser.check_error_plots(line.split(": ", 1)[1].strip(), n_plots, timeout_s=300)
    finally:
        viewer.terminate()
        viewer.communicate(timeout=30)
    if check.png:
        (shots / f"view_serve_web_{run}.png").write_bytes(check.png)
    return _figure(check)


def run(args) -> dict:
    quick = bool(getattr(args, "quick", False))
    folder = pathlib.Path(getattr(args, "out_dir", "bench_out")) / "view"
    folder.mkdir(parents=True, exist_ok=True)
    demo = folder / "demo"
    figures: dict = {"load_average_1min": round(os.getloadavg()[0], 2),
                     "demo": _demo(demo, 6.0 if quick else 12.0)}
    figures["bag_to_rrd_demo_bag"] = _throughput(demo / "bag", folder)
    synthetic = _synthetic_bag(folder / "synthetic_bag", 500 if quick else 5000)
    figures["bag_to_rrd_synthetic"] = _throughput(synthetic, folder)
    n_plots = len(error_components(read_bag(demo / "bag")))        # one plot each in the blueprint
    figures["error_plots_in_blueprint"] = n_plots
    if not browser.CHROMIUM.exists():
        figures["browser"] = f"skipped: {browser.CHROMIUM} is missing (./setup.sh --with-browser)"
        return figures
    figures["browser_demo_rrd"] = _browser_rrd(demo / "demo.rrd", n_plots, folder)
    for k in range(1 if quick else RUNS):
        figures[f"browser_view_serve_web_{k + 1}"] = _browser_serve_web(demo / "bag", n_plots, folder, k + 1)
    figures["screenshots"] = str(folder)
    return figures
