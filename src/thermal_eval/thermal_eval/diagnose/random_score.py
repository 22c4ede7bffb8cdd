"""Run the mismatch finder on drawn cases and score what it answered.

:func:`run_case` diagnoses one drawn case (:mod:`random_cases`, :mod:`random_recording`) against
the unmodified preset and returns a plain outcome; :func:`score` turns outcomes into the figures
of ``thermal-comp bench diagnose --random`` and :func:`markdown` into its tables. Definitions:

- *true effect first*: the answer's effect type is the concealed one (either one on a two-effect case);
- *exact target*: the first adopted effect has the concealed effect's type and target; *or in
  set*: or the concealed one is in the first adopted effect's indistinguishable set;
- *extra adoptions*: adopted effects whose (type, target) is not concealed, plus an ``unnamed``
  term beside a named answer; on a none-case everything adopted or unnamed is extra;
- *parameter error*: |fitted - true| / |true| of the amplitude parameter on exact answers;
- *held-out cut*: fall of the noise-weighted held-out sum of squares over all channels, from
  the report's own ``holdout_rmse_before/after`` and ``noise_sigma``;
- *a channel worse*: its held-out RMSE after exceeds before by 5 % and by half its noise sigma
  (the report's sigma); *beyond noise*: by half the larger of that and the generator's noise RMS.
"""
from __future__ import annotations

import time
from collections import Counter

import numpy as np

from thermal_eval.diagnose.random_cases import draw_case, twin_spec
from thermal_eval.diagnose.random_recording import case_recording
from thermal_twin.diagnose.diagnosis import diagnose

WORSE_REL = 0.05
WORSE_SIGMA = 0.5
SIZE_BINS = ((0.0, 2.0), (2.0, 5.0), (5.0, 15.0), (15.0, float("inf")))


def _key(s: dict) -> str:
    return f"{s['effect']}:{s['target']}"


def _channel_figures(rep: dict, noise: dict | None = None) -> tuple[float | None, list[str], list[str]]:
    """(held-out cut, channels worse by the report's noise sigma, channels worse by the larger
    of that and the generator's own noise RMS of the channel's kind): the finder's sigma comes
    from second differences and is far below the RMS of strongly coloured noise, whose slow
    part moves a channel's held-out RMSE whatever the twin does."""
    before = after = 0.0
    worse, worse_noise = [], []
    for ch, d in rep["channels"].items():
        b, a, s = d.get("holdout_rmse_before"), d.get("holdout_rmse_after"), d.get("noise_sigma")
        if b is None or a is None or not s:
            continue
        before += (b / s) ** 2
        after += (a / s) ** 2
        up = a > b * (1 + WORSE_REL)
        if up and a - b > WORSE_SIGMA * s:
            worse.append(ch)
        true_s = (noise or {}).get("sigma_k" if d.get("unit") == "degC" else "sigma_um", 0.0)
        if up and a - b > WORSE_SIGMA * max(s, true_s):
            worse_noise.append(ch)
    cut = 100.0 * (1.0 - after / before) if before > 0 else None
    return cut, worse, worse_noise


def run_case(shared: dict, item: tuple[int, int]) -> dict:
    """Draw, build and diagnose case ``item = (seed, index)``; ``shared['calibrate']`` runs
    ``diagnose --calibrate``. Never raises for a failed diagnosis: the outcome says ``error``."""
    seed, index = item
    case = draw_case(seed, index)
    t0 = time.perf_counter()
    rec, truth = case_recording(case)
    build_s = time.perf_counter() - t0
    out = {"seed": seed, "index": index, "label": case.label, "twin": case.twin, "scenario": case.scenario,
           "kind": case.kind, "size": case.size, "size_measured": truth["size_measured"],
           "onset_h": case.onset_h, "noise": case.noise, "rows": len(rec), "hours": case.hours,
           "true_keys": [f"{h.effect}:{h.target}" for h in truth["hidden"]],
           "true_types": [h.effect for h in truth["hidden"]],
           "true_values": [list(h.values) for h in truth["hidden"]],
           "oov": [o.key for o in case.oov], "build_s": build_s}
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        rep = diagnose(twin_spec(case.twin), rec, calibrate=bool(shared.get("calibrate"))).report
    except Exception as exc:        # a crash is an outcome of the benchmark, not its end
        out.update({"error": f"{exc.__class__.__name__}: {exc}", "answer": "error", "selected": [],
                    "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0})
        return out
    sel = [] if rep["selected"] == "none" else rep["selected"]
    cut, worse, worse_noise = _channel_figures(rep, case.noise)
    cal = rep.get("calibration") or {}
    out.update({"answer": rep["answer"], "selected": [_key(s) for s in sel],
                "selected_params": [[p["value"] for p in s["params"].values()] for s in sel],
                "selected_sets": [[":".join(w["other"].split(":")[:2]) for w in s.get("tell_apart", [])]
                                  for s in sel],
                "unnamed": [u.get("formula") for u in (rep.get("unnamed") or [])],
                "holdout_cut_pct": cut, "worse_channels": worse,
                "worse_channels_beyond_noise": worse_noise,
                "moved": [m["name"] for m in cal.get("mis_calibrated", [])],
                "clock_shift_s": (rep.get("clock_offset") or {}).get("shift_s"),
                "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
                "simulations": rep.get("simulations")})
    return out


def judge(o: dict) -> dict:
    """Per-case verdicts used by :func:`score` (also printed on the progress line)."""
    sel, true = o.get("selected", []), o["true_keys"]
    first = bool(true) and o["answer"] in o["true_types"]
    exact = bool(true) and bool(sel) and sel[0] in true
    extra = sum(k not in true for k in sel) + (bool(o.get("unnamed")) and bool(true))
    if o["kind"] in ("none", "unnamed"):
        extra = len(sel) + (o["kind"] == "none" and bool(o.get("unnamed")))
    perr = None
    if exact:
        v_true = o["true_values"][true.index(sel[0])][0]
        v_fit = o["selected_params"][0][0]
        perr = abs(v_fit - v_true) / abs(v_true) if v_true else None
    sets = o.get("selected_sets") or [[]]
    in_set = exact or (bool(true) and bool(sel) and any(k in true for k in sets[0]))
    return {"first": first, "exact": exact, "in_set": in_set, "extra": int(extra), "param_err": perr,
            "both": o["kind"] == "two" and set(true) <= set(sel),
            "right": {"none": o["answer"] == "none", "unnamed": o["answer"] == "unnamed"}.get(o["kind"],
                                                                                          first)}


def _pct(k: int, n: int) -> float | None:
    return round(100.0 * k / n, 1) if n else None


def _true_class(o: dict) -> str:
    return o["true_types"][0] if o["kind"] in ("named", "two") else o["kind"]


def score(outcomes: list[dict], wall_s: float | None = None) -> dict:
    """Figures of a run: per kind, per effect type, per measured size, the confusion matrix, time."""
    js = [(o, judge(o)) for o in outcomes]
    single = [(o, j) for o, j in js if o["kind"] == "named"]
    two = [(o, j) for o, j in js if o["kind"] == "two"]
    none = [(o, j) for o, j in js if o["kind"] == "none"]
    oov = [(o, j) for o, j in js if o["kind"] == "unnamed"]
    perr = [j["param_err"] for _, j in js if j["param_err"] is not None]
    cuts = [o["holdout_cut_pct"] for o, _ in js if o.get("holdout_cut_pct") is not None and o.get("selected")]
    walls = [o["wall_s"] for o in outcomes]
    fig = {
        "cases": len(outcomes), "errors": sum(o["answer"] == "error" for o in outcomes),
        "single_cases": len(single),
        "single_true_effect_first_pct": _pct(sum(j["first"] for _, j in single), len(single)),
        "single_exact_target_pct": _pct(sum(j["exact"] for _, j in single), len(single)),
        "single_exact_target_or_in_set_pct": _pct(sum(j["in_set"] for _, j in single), len(single)),
        "extra_adoptions_per_case": round(sum(j["extra"] for _, j in js) / max(len(js), 1), 3),
        "two_effect_cases": len(two), "two_both_found_pct": _pct(sum(j["both"] for _, j in two), len(two)),
        "two_one_first_pct": _pct(sum(j["first"] for _, j in two), len(two)),
        "none_cases": len(none), "none_answered_pct": _pct(sum(j["right"] for _, j in none), len(none)),
        "oov_cases": len(oov), "oov_unnamed_pct": _pct(sum(j["right"] for _, j in oov), len(oov)),
        "oov_vocabulary_word_pct": _pct(sum(o["answer"] not in ("unnamed", "none", "error") for o, _ in oov), len(oov)),
        "param_rel_err_median": round(float(np.median(perr)), 3) if perr else None,
        "holdout_cut_pct_median": round(float(np.median(cuts)), 1) if cuts else None,
        "cases_with_a_channel_worse": sum(bool(o.get("worse_channels")) for o in outcomes),
        "cases_with_a_channel_worse_beyond_noise": sum(bool(o.get("worse_channels_beyond_noise"))
                                                       for o in outcomes),
        "diagnosis_wall_s_median": round(float(np.median(walls)), 1) if walls else None,
        "diagnosis_wall_s_max": round(float(max(walls)), 1) if walls else None,
        "diagnosis_cpu_s_median": round(float(np.median([o["cpu_s"] for o in outcomes])), 1) if walls else None,
    }
    if wall_s:
        fig["cases_per_minute"] = round(60.0 * len(outcomes) / wall_s, 2)
    fig["per_type"] = _per_type(single)
    fig["per_size"] = _per_size(single)
    fig["per_condition"] = _per_condition(js)
    fig["confusion"] = _confusion(outcomes)
    return fig


def _per_type(single: list) -> dict:
    out: dict = {}
    for ty in sorted({o["true_types"][0] for o, _ in single}):
        sub = [j for o, j in single if o["true_types"][0] == ty]
        out[ty] = {"n": len(sub), "first_pct": _pct(sum(j["first"] for j in sub), len(sub)),
                   "exact_pct": _pct(sum(j["exact"] for j in sub), len(sub))}
    return out


def _per_size(single: list) -> dict:
    out: dict = {}
    for lo, hi in SIZE_BINS:
        sub = [j for o, j in single if lo <= o["size_measured"] < hi]
        out[f"{lo:g}-{hi:g}"] = {"n": len(sub), "first_pct": _pct(sum(j["first"] for j in sub), len(sub)),
                                 "exact_pct": _pct(sum(j["exact"] for j in sub), len(sub))}
    return out


CONDITIONS = {
    "clock offset": lambda o: bool(o["noise"].get("clock_offset_s")),
    "no clock offset": lambda o: not o["noise"].get("clock_offset_s"),
    "onset part-way": lambda o: o.get("onset_h", 0.0) > 0,
    "white noise": lambda o: o["noise"].get("colour") == "white",
    "AR(1) noise": lambda o: o["noise"].get("colour") == "ar1",
    "random-walk noise": lambda o: o["noise"].get("colour") == "random_walk",
    "dropped rows": lambda o: o["noise"].get("drop_fraction", 0.0) > 0,
}


def _per_condition(js: list) -> dict:
    """Right answers (true type first on effect cases, ``none``/``unnamed`` on the others) and
    ``unnamed`` answers on cases without out-of-vocabulary physics, per recording condition."""
    out: dict = {}
    for name, has in CONDITIONS.items():
        sub = [(o, j) for o, j in js if "noise" in o and has(o)]
        vocab = [o for o, _ in sub if o["kind"] != "unnamed"]
        out[name] = {"n": len(sub), "right_pct": _pct(sum(bool(j["right"]) for _, j in sub), len(sub)),
                     "unnamed_without_oov": f"{sum(o['answer'] == 'unnamed' for o in vocab)}/{len(vocab)}"}
    return out


def _confusion(outcomes: list[dict]) -> dict:
    """{true class: {answer: count}}; the true class of a two-effect case is its first effect."""
    m: dict = {}
    for o in outcomes:
        m.setdefault(_true_class(o), Counter())[o["answer"]] += 1
    return {k: dict(v) for k, v in sorted(m.items())}
