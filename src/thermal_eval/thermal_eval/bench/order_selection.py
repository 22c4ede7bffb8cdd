"""Speed of ARX order selection: batched versus per-candidate evaluation.

One :func:`talc_model.arx.order_selection.select_orders` call on a TALC-sized problem: the
synthetic plant's 200 h on a 5-min grid (2,400 samples), its three TALC inputs, one error
component (E_Y0C) with probe noise, a probe every 2 h and weight 0.05 on the samples in
between (as TALC weighs predicted samples), n_a 0..1 and n_b 1..10 per input (Table 6.1):
2,000 candidates, scored exhaustively. Timed for the batched evaluation (``select_orders``)
and for the per-candidate one it replaced (``_select_orders_reference``: a ``fit_arx`` and
an ``ArxModel.simulate`` per candidate), in pure simulation and with TALC's state updates,
plus the coordinate search (``exhaustive_limit`` below the grid size) that
``bench_model`` times, and with a fourth input (the C-axis speed, an NC signal like the
sweep's MWF state), whose 10,000 candidates exceed ``exhaustive_limit`` (4,000) so that the
coordinate search runs, as in ``thermal-comp sweep`` with its four default inputs. Figures (keys ``order_selection.<case>.*``): ``batched_s`` and
``per_candidate_s`` (median of ``repeats``, single-threaded BLAS as in production),
``speedup``, ``candidates``, ``same_result`` (same orders, and score and theta within 1e-9
relative). Call :func:`run` (``args.quick``: one repeat).
"""
from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

from talc_model.arx.order_selection import _select_orders_reference, select_orders
from thermal_twin.sim.synthetic_plant import make_plant, probe_noise_std

COMPONENT = "E_Y0C"
CASES = {
    "exhaustive_2000": {"na_range": (0, 1), "nb_range": (1, 10), "state_updates": False},
    "exhaustive_2000_state_updates": {"na_range": (0, 1), "nb_range": (1, 10), "state_updates": True},
    "coordinate_1x10": {"na_range": (1, 1), "nb_range": (1, 10), "state_updates": False,
                        "exhaustive_limit": 200},
    "coordinate_4_inputs": {"na_range": (1, 1), "nb_range": (1, 10), "state_updates": False,
                            "inputs": "u4"},
}


def problem(hours: float = 200.0, step_s: float = 300.0, seed: int = 11) -> dict[str, np.ndarray]:
    """y, u (3 temperatures), u4 (and the C-axis speed), weights and measured mask of the
    benchmark problem (fixed seed)."""
    plant = make_plant(hours=hours, step_s=step_s, seed=seed)
    t = plant.temperatures
    u = np.column_stack([t["ambient"] - t["ambient"][0], t["ws"] - t["ws"][0],
                         (t["c_coolant_out"] - t["c_coolant_in"])
                         - (t["c_coolant_out"][0] - t["c_coolant_in"][0])])
    rng = np.random.default_rng(seed)
    y = plant.errors[COMPONENT] + rng.normal(0.0, probe_noise_std()[COMPONENT], u.shape[0])
    measured = np.zeros(u.shape[0], bool)
    measured[:: int(round(7200.0 / step_s))] = True          # a probe every 2 h
    u4 = np.column_stack([u, plant.machine_state["c_axis_rpm"] / 1000.0])
    return {"y": y, "u": u, "u4": u4, "weights": np.where(measured, 1.0, 0.05), "measured": measured}


def _timed(fn, repeats: int):
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def order_selection_speed(repeats: int = 3) -> dict[str, Any]:
    """Time one select_orders call per case, batched versus per candidate."""
    p = problem()
    out: dict[str, Any] = {}
    for name, case in CASES.items():
        kw = dict(case)
        na_range, nb_range, u = kw.pop("na_range"), kw.pop("nb_range"), p[kw.pop("inputs", "u")]

        def call(fn, kw=kw, na_range=na_range, nb_range=nb_range, u=u):
            return fn(p["y"], u, na_range, nb_range, weights=p["weights"],
                      measured=p["measured"], **kw)

        t_new, new = _timed(lambda: call(select_orders), repeats)
        t_old, old = _timed(lambda: call(_select_orders_reference), repeats)
        same = (new.orders == old.orders
                and abs(new.score - old.score) <= 1e-9 * abs(old.score)
                and bool(np.allclose(new.model.theta, old.model.theta, rtol=1e-9, atol=0)))
        key = f"order_selection.{name}"
        out[f"{key}.candidates"] = new.candidates_tried
        out[f"{key}.batched_s"] = round(t_new, 4)
        out[f"{key}.per_candidate_s"] = round(t_old, 3)
        out[f"{key}.speedup"] = round(t_old / t_new, 1)
        out[f"{key}.same_result"] = bool(same)
    return out


def run(args) -> dict[str, Any]:
    """Benchmark entry (``args.quick``: one repeat instead of three); prints the figures."""
    figures = order_selection_speed(1 if getattr(args, "quick", False) else 3)
    for k, v in figures.items():
        print(f"{k}: {v}")
    return figures


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat instead of three")
    run(ap.parse_args())
