"""Anchor the scale of an estimated input physically: the coolant's energy balance and the declared range.

The temperatures measure heat, not speed: an input estimated from them
(:mod:`thermal_twin.calibrate.input_estimation`) has its scale only through the twin's own sources
driven by it, and when the temperatures cannot locate heat on those sources' nodes (a motor
whose heat leaves through its cooling jacket) the scale is not identified. Two physical
anchors, opt-in:

(a) *the coolant's energy balance*: the jacket's heat leaves with the coolant, so the return
    temperature rises above the supply by Q / (m_dot c_p). The return's rise above its
    ``quantile`` level (the supply: the return is lowest when no heat flows into the jacket)
    times a heat-per-kelvin W is the heat of the input-driven sources in the jacket.
    W is a twin parameter fitted like the others, on the training rows of a recording that
    *has* the input (:func:`coolant_balance`); on a recording that lacks it, the scale s of
    the estimated input's shape is the one whose jacket-source heat P(s u) matches W x rise.
(b) *the declared range*: a value beyond the input's declared maximum is not a value of that
    input; s is capped so that s u never exceeds it (``rated_max`` below the schema's range).

:func:`alternate_anchored` is :func:`thermal_twin.calibrate.input_alternation.alternate` with the
anchored estimate. Rule, figures and limits: docs/calibrate.md ("Inputs the recording lacks").
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

from thermal_twin.calibrate.input_alternation import Alternation, alternate
from thermal_twin.calibrate.input_estimation import InputEstimate, fill_missing_inputs
from thermal_twin.machine.schema import Machine
from thermal_comp_common.recording_csv import Recording


class ScaleAnchorError(ValueError):
    """The anchor cannot be built or applied; names the field and value."""


@dataclass(frozen=True)
class CoolantBalance:
    input: str                          # the estimated input (spindle_rpm)
    column: str                         # the coolant return's column (t4_c)
    sources: dict[str, tuple[float, float]]   # jacket sources driven by ``input``: (coefficient, exponent)
    level: float                        # the return's ``quantile`` level: the supply temperature
    quantile: float
    heat_per_kelvin: float              # W = m_dot c_p [W/K], fitted on the training blocks
    fit_corr: float                     # training blocks: corr(W x rise, jacket-source heat)
    block_s: float

    def heat(self, u: np.ndarray) -> np.ndarray:
        """Heat of the jacket's sources at input values ``u``."""
        u = np.abs(np.asarray(u, dtype=float))
        return sum(c * u ** n for c, n in self.sources.values())


def _blocks(t: np.ndarray, x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    ok = np.isfinite(x)
    cnt = np.bincount(k[ok], minlength=len(edges) - 1)
    tot = np.bincount(k[ok], weights=x[ok], minlength=len(edges) - 1)
    return np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)


def jacket_sources(machine: Machine, name: str, boundary_input: str) -> dict[str, tuple[float, float]]:
    """The sources driven by ``name`` on nodes linked to the boundary whose temperature is
    ``boundary_input`` (the nodes the jacket cools)."""
    bounds = {b for b, spec in machine.to_dict()["boundaries"].items() if spec.get("temperature") == boundary_input}
    if not bounds:
        raise ScaleAnchorError(f"boundary_input '{boundary_input}': no boundary of twin '{machine.name}' "
                               f"takes its temperature from it")
    cooled = {n for lk in machine.to_dict()["links"].values() for n in lk["between"]
              if set(lk["between"]) & bounds} - bounds
    src = {k: (s.coefficient, s.exponent) for k, s in machine.sources.items() if s.input == name and s.node in cooled}
    if not src:
        raise ScaleAnchorError(f"input '{name}': no source driven by it sits on a node cooled by "
                               f"'{boundary_input}' ({sorted(cooled)})")
    return src


def coolant_balance(machine: Machine, rec: Recording, name: str, boundary_input: str, n_train: int,
                    block_s: float = 1800.0, quantile: float = 0.05) -> CoolantBalance:
    """Fit W = m_dot c_p on the first ``n_train`` rows of ``rec`` (which has ``name``):
    block means of the jacket sources' heat at the recorded input against block means of the
    return's rise above its ``quantile`` level, least squares through the origin."""
    if name not in rec.columns:
        raise ScaleAnchorError(f"input '{name}': the recording used to fit the coolant balance lacks it")
    if not 0.0 <= quantile < 0.5:
        raise ScaleAnchorError(f"quantile: {quantile!r} must be in [0, 0.5)")
    if not 8 <= n_train <= len(rec):
        raise ScaleAnchorError(f"n_train: {n_train!r} must be between 8 and the recording's {len(rec)} rows")
    column = _return_column(machine, rec, boundary_input)
    src = jacket_sources(machine, name, boundary_input)
    t = rec.time_s[:n_train]
    ret = np.asarray(rec.columns[column], dtype=float)
    level = float(np.nanquantile(ret[:n_train], quantile))
    edges = np.arange(t[0], t[-1] + block_s, block_s)
    rise = _blocks(t, ret[:n_train] - level, edges)
    heat = _blocks(t, sum(c * np.abs(np.asarray(rec.columns[name][:n_train], dtype=float)) ** n
                          for c, n in src.values()), edges)
    ok = np.isfinite(rise) & np.isfinite(heat)
    if ok.sum() < 3 or float(np.sum(rise[ok] ** 2)) <= 0:
        raise ScaleAnchorError(f"column '{column}': its rise above the {quantile:g} level is zero or too short "
                               f"on the training rows: no coolant balance")
    corr = float(np.corrcoef(rise[ok], heat[ok])[0, 1])
    if not corr > 0:
        raise ScaleAnchorError(f"column '{column}': its rise falls as the jacket's heat grows (block corr "
                               f"{corr:.3g}): it is not the return of that jacket")
    w = float(np.sum(rise[ok] * heat[ok]) / np.sum(rise[ok] ** 2))
    return CoolantBalance(name, column, src, level, quantile, w, corr, block_s)


def _return_column(machine: Machine, rec: Recording, boundary_input: str) -> str:
    spec = machine.inputs.get(boundary_input)
    if spec is None:
        raise ScaleAnchorError(f"boundary_input '{boundary_input}': not an input of twin '{machine.name}'")
    col = f"{spec.from_sensor}_c" if spec.from_sensor else boundary_input
    if col not in rec.columns:
        raise ScaleAnchorError(f"boundary_input '{boundary_input}': the recording has no column '{col}'")
    return col


def anchor_scale(est: InputEstimate, balance: CoolantBalance, rec: Recording,
                 max_input: float) -> tuple[float, bool]:
    """(s, capped): the factor on ``est``'s equivalent input whose jacket-source heat best
    matches W x the return's rise (block means of ``rec``), capped so that s u <= ``max_input``."""
    if est.input != balance.input:
        raise ScaleAnchorError(f"estimate of '{est.input}' cannot be anchored by a balance of '{balance.input}'")
    if not max_input > 0:
        raise ScaleAnchorError(f"max_input: {max_input!r} must be positive")
    if balance.column not in rec.columns:
        raise ScaleAnchorError(f"column '{balance.column}': not in the recording to anchor")
    ret = np.asarray(rec.columns[balance.column], dtype=float)
    target = balance.heat_per_kelvin * _blocks(rec.time_s, ret - balance.level, est.block_edges_s)
    u = np.asarray(est.equivalent_input, dtype=float)
    ok = np.isfinite(target)
    if not ok.any() or np.max(u) <= 0:
        raise ScaleAnchorError(f"estimate of '{est.input}': no block with both a speed shape and a return level")
    s_max = max_input / float(np.max(u))
    res = minimize_scalar(lambda s: float(np.sum((balance.heat(s * u[ok]) - target[ok]) ** 2)),
                          bounds=(0.0, 4.0 * s_max), method="bounded", options={"xatol": 1e-6})
    s = float(res.x)
    return (s_max, True) if s > s_max else (s, False)


def anchored_estimate(est: InputEstimate, balance: CoolantBalance, rec: Recording, machine: Machine,
                      rated_max: float | None = None) -> tuple[InputEstimate, str]:
    """``est`` with its equivalent input rescaled by :func:`anchor_scale` and a note. The cap
    is ``rated_max`` if given (it must lie within the input's declared range), else the
    declared maximum."""
    declared = machine.inputs[est.input].max
    if rated_max is not None and not 0 < rated_max <= declared:
        raise ScaleAnchorError(f"rated_max: {rated_max!r} must be in (0, {declared:g}] (the declared range of "
                               f"'{est.input}')")
    cap = declared if rated_max is None else float(rated_max)
    s, capped = anchor_scale(est, balance, rec, cap)
    out = dataclasses.replace(est, equivalent_input=s * np.asarray(est.equivalent_input, dtype=float),
                              scale_identified=True)
    note = (f"the scale of {est.input} anchored by the coolant balance ({balance.column} above "
            f"{balance.level:.2f} degC x {balance.heat_per_kelvin:.1f} W/K = the heat of "
            f"{', '.join(balance.sources)}): x{s:.3f}, mean {np.mean(out.equivalent_input):.0f}, max "
            f"{np.max(out.equivalent_input):.0f} {machine.inputs[est.input].unit}"
            + (f" (capped at {cap:g}: the balance asked for more)" if capped else ""))
    return out, note


def anchored_fill(machine: Machine, rec: Recording, channels: list[str], balance: CoolantBalance,
                  block_s: float = 1800.0, responses: list[str] = (), rated_max: float | None = None
                  ) -> tuple[Recording, list[InputEstimate], list[str]]:
    """:func:`thermal_twin.calibrate.input_estimation.fill_missing_inputs` with the anchored scale
    for the balance's input (other missing inputs as estimated)."""
    filled, ests, notes = fill_missing_inputs(machine, rec, channels, block_s=block_s, responses=responses)
    cols = dict(filled.columns)
    for i, e in enumerate(ests):
        if e.input == balance.input:
            ests[i], note = anchored_estimate(e, balance, rec, machine, rated_max)
            cols[e.input] = ests[i].input_series(rec.time_s)
            notes[i] = f"{notes[i]}; {note}"
    return Recording(rec.time_s, cols, source=rec.source, warnings=list(rec.warnings)), ests, notes


def alternate_anchored(spec: dict, rec: Recording, balance: CoolantBalance, responses: list[str] = (),
                       rounds: int = 3, block_s: float = 1800.0, rated_max: float | None = None,
                       progress: Callable[[str], None] | None = None, **diagnose_kw) -> Alternation:
    """:func:`thermal_twin.calibrate.input_alternation.alternate` (same rule, same return type) with
    every round's estimate anchored by ``balance`` (:func:`anchored_fill`)."""
    return alternate(spec, rec, responses=responses, rounds=rounds, block_s=block_s, progress=progress,
                     fill=functools.partial(anchored_fill, balance=balance, rated_max=rated_max), **diagnose_kw)
