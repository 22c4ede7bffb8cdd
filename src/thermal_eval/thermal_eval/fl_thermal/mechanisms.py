"""Every mechanism of a calibrated twin, how to remove it, and whether the recording supports it.

The ablation conceals mechanisms of a twin calibrated on a real recording and checks that the
mismatch finder names them back. Only a mechanism the recording *supports* can
be named back: one whose removal makes the calibrated twin's held-out fit clearly worse.
:func:`all_mechanisms` lists every mechanism of a machine description (each source, each
link incl. those to the coolant and between inner nodes, each thermo-elastic term of every
channel, each sensor's lag, calibrated bias and coupling to a second node) with the word of
the finder's vocabulary that names it (``None`` when no word does: a constant source, a
sensor's mixing weights). :func:`screen` measures each removal's
held-out SSE ratio with the calibrated twin alone (one simulation each, no diagnosis), and
:func:`select` applies the selection rule stated in docs/diagnose.md before any diagnosis.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Callable

import numpy as np

from thermal_twin.diagnose.fit import FitProblem

#: a removal is "supported" when it raises the held-out weighted SSE by at least this factor
MIN_RATIO = 1.2


@dataclass(frozen=True)
class Mechanism:
    label: str
    kind: str                          # source | link | gain | sensor
    expect: str | None                 # effect:target the finder should name first (None: no word)
    param: str | None                  # the fitted parameter compared with the calibrated value
    remove: Callable[[dict], float]    # removes the mechanism in place, returns its reference value
    override: str | None = None        # the calibration parameter this mechanism is (for bound checks)


def _drop_override(spec: dict, name: str) -> None:
    """A removed parameter leaves the twin's calibration section too (else the ablated
    description names a parameter it no longer has and is invalid)."""
    (spec.get("calibration") or {}).get("parameters", {}).pop(name, None)


def _source(spec: dict, name: str, umax: float) -> float:
    _drop_override(spec, f"sources.{name}.coefficient")
    _drop_override(spec, f"sources.{name}.power")
    s = spec["sources"].pop(name)
    if s.get("input"):
        return float(s["coefficient"]) * umax ** float(s.get("exponent", 1.0))
    return float(s.get("power", 0.0))


def _link(spec: dict, name: str) -> float:
    _drop_override(spec, f"links.{name}.conductance")
    return float(spec["links"].pop(name)["conductance"])


def _gain(spec: dict, channel: str, node: str) -> float:
    _drop_override(spec, f"errors.{channel}.terms.{node}")
    return float(spec["errors"][channel]["terms"].pop(node))


def _lag(spec: dict, sensor: str) -> float:
    lag = float(spec["sensors"][sensor].get("lag_s", 0.0))
    spec["sensors"][sensor]["lag_s"] = 0.0
    return lag


def _bias(spec: dict, sensor: str) -> float:
    _drop_override(spec, f"sensors.{sensor}.bias")
    return float(spec["sensors"][sensor].pop("bias", 0.0))


def _coupling(spec: dict, sensor: str) -> float:
    """The sensor reads its main node only; returns the weight it had on the others."""
    of = spec["sensors"][sensor]["of"]
    main = max(of, key=lambda k: float(of[k]))
    spec["sensors"][sensor]["of"] = main
    return float(sum(float(w) for k, w in of.items() if k != main))


def _ambient(spec: dict) -> str:
    return next((b for b in spec["boundaries"] if "ambient" in b), "ambient")


def all_mechanisms(spec: dict, umax: float) -> list[Mechanism]:
    """Every removable mechanism of ``spec`` (see the module docstring)."""
    out: list[Mechanism] = []
    for name, s in spec["sources"].items():
        driven = bool(s.get("input"))
        out.append(Mechanism(f"source {name}" + (f" ({s['input']}-driven)" if driven else " (constant)"),
                             "source", f"heat_source:{s['node']}" if driven else None,
                             "P_max" if driven else None, lambda sp, n=name: _source(sp, n, umax),
                             f"sources.{name}.coefficient" if driven else f"sources.{name}.power"))
    amb = _ambient(spec)
    order = {n: i for i, n in enumerate(list(spec["nodes"]) + list(spec["boundaries"]))}
    for name, d in spec["links"].items():
        a, b = sorted(d["between"], key=order.__getitem__)
        # the finder's words: an ambient link is ambient_coupling:<node>, any other a new
        # conduction path <node>/<node or boundary> (mismatch_effects.unlinked_pairs's order)
        expect, par = (f"ambient_coupling:{a}", "dG") if b == amb else (f"conduction:{a}/{b}", "G")
        out.append(Mechanism(f"link {name} ({a}-{b})", "link", expect, par,
                             lambda sp, n=name: _link(sp, n), f"links.{name}.conductance"))
    for ch, e in spec["errors"].items():
        for node in e["terms"]:
            out.append(Mechanism(f"thermo-elastic term {ch}/{node}", "gain", f"elastic_gain:{ch}/{node}",
                                 "d_gain", lambda sp, c=ch, n=node: _gain(sp, c, n), f"errors.{ch}.terms.{node}"))
    for sid, d in spec["sensors"].items():
        if float(d.get("lag_s", 0.0)) > 0:
            out.append(Mechanism(f"lag of sensor {sid}", "sensor", f"time_lag:{sid}", "tau",
                                 lambda sp, s=sid: _lag(sp, s)))
        if abs(float(d.get("bias", 0.0))) > 0.5 * float(d.get("resolution", 0.0)):
            out.append(Mechanism(f"calibrated bias of sensor {sid}", "sensor", f"sensor_bias:{sid}", "bias",
                                 lambda sp, s=sid: _bias(sp, s), f"sensors.{sid}.bias"))
        if isinstance(d.get("of"), dict) and len(d["of"]) > 1:
            out.append(Mechanism(f"coupling of sensor {sid} to a second node", "sensor", None, None,
                                 lambda sp, s=sid: _coupling(sp, s)))
    return out


def holdout_by_channel(problem: FitProblem, spec: dict) -> np.ndarray:
    """Held-out weighted SSE of every channel of ``problem`` for the twin ``spec``."""
    return np.sum(problem.weighted_residual(problem.outputs(spec), problem.n_train) ** 2, axis=1)


def ratios_by_channel(problem: FitProblem, a: np.ndarray, b: np.ndarray, k: int = 4) -> list[tuple[str, float]]:
    """The k channels whose held-out SSE changes most from ``a`` to ``b`` (ratio b / a,
    furthest from 1): what the held-out score of a removal is made of."""
    ratio = [(c, float(b[i] / a[i])) for i, c in enumerate(problem.channels) if a[i] > 0]
    return sorted(ratio, key=lambda x: -abs(np.log(max(x[1], 1e-12))))[:k]


def screen(problem: FitProblem, spec_c: dict, mechs: list[Mechanism],
           at_bound: set[str] = frozenset()) -> list[dict]:
    """Each mechanism's removal scored with the calibrated twin ``spec_c`` alone: held-out
    SSE ratio ablated / calibrated, the channels it changes most, whether its calibrated
    value sits at a calibration bound (``at_bound``: parameter names)."""
    base = holdout_by_channel(problem, spec_c)
    rows = []
    for m in mechs:
        s = copy.deepcopy(spec_c)
        ref = m.remove(s)
        per = holdout_by_channel(problem, s)
        rows.append({"mechanism": m.label, "kind": m.kind, "expected": m.expect, "reference": ref,
                     "ratio": float(np.sum(per) / np.sum(base)), "at_bound": m.override in at_bound,
                     "most_changed": ratios_by_channel(problem, base, per)})
    return rows


def select(mechs: list[Mechanism], rows: list[dict], min_ratio: float = MIN_RATIO) -> list[Mechanism]:
    """The selection rule (fixed before any diagnosis; it uses the calibrated twin only):
    every mechanism that a word of the vocabulary names, whose removal raises the held-out
    SSE by at least ``min_ratio`` and whose calibrated value is not at a calibration bound
    (a value at its bound is the calibration saying the twin's form is wrong there: no
    reference to recover), highest ratio first."""
    ok = [(r["ratio"], i) for i, (m, r) in enumerate(zip(mechs, rows))
          if m.expect and r["ratio"] >= min_ratio and not r["at_bound"]]
    return [mechs[i] for _, i in sorted(ok, key=lambda x: -x[0])]


def screen_markdown(rows: list[dict]) -> str:
    """The screening table of docs/diagnose.md."""
    L = ["| mechanism | kind | vocabulary word | calibrated value | held-out SSE ablated / calibrated "
         "| at a calibration bound | identifiable: best competitor, share it leaves "
         "| channels it changes most (held-out SSE x) |",
         "|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: -r["ratio"]):
        ident = ("-" if r.get("identifiable") is None else
                 f"{'yes' if r['identifiable'] else 'no'}: {r['competitor']}, {r['distinct']:.3f}")
        L.append(f"| {r['mechanism']} | {r['kind']} | {r['expected'] or '(none)'} | {r['reference']:.4g} "
                 f"| {r['ratio']:.3f} | {'yes' if r['at_bound'] else 'no'} | {ident} "
                 f"| {', '.join(f'{c} {x:.2f}' for c, x in r['most_changed'])} |")
    return "\n".join(L)
