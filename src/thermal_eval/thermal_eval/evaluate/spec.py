"""What ``thermal-comp evaluate`` reads from a recording: columns, units and the split by time.

Any recording (CSV with or without BOM, Excel-style, or a bag) is read by the one reader of
real files (:func:`thermal_twin.calibrate.column_mapping.read_real_recording`, with its column mapping);
this module picks the temperatures, displacement channels and optional machine inputs (by
name or glob pattern; by default by the project's column kinds), converts units to degC and
um, and cuts the rows chronologically into train / validation / test (fractions or row
numbers). A spec is a dict or YAML file; FL_THERMAL is one such spec (:data:`FL_THERMAL_SPEC`).
Unknown names raise :class:`SpecError` naming the column and its closest match.
"""
from __future__ import annotations

import difflib
import fnmatch
import math
import pathlib
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import yaml

from thermal_comp_common.recording_csv import Recording, column_kind
from thermal_twin.calibrate.column_mapping import ColumnMapping, parse_mapping, read_real_recording

#: displacement units -> factor to um; temperature units -> (factor, offset) to degC
LENGTH_UNITS = {"um": 1.0, "mm": 1000.0, "nm": 0.001, "m": 1e6, "in": 25400.0}
TEMPERATURE_UNITS = {"C": (1.0, 0.0), "degC": (1.0, 0.0), "K": (1.0, -273.15), "F": (5.0 / 9.0, -32.0 * 5.0 / 9.0)}
SPEC_KEYS = ("temperatures", "displacements", "inputs", "units", "split", "mapping", "relative_to_first_row",
             "name", "temperatures_topic", "errors_topic", "sample_period_s")
DEFAULT_SPLIT = {"train": 0.6, "validation": 0.2, "test": 0.2, "order": ["validation", "test"]}


class SpecError(ValueError):
    """A bad evaluation spec or a column the recording lacks; the message names it."""


def closest(name: str, pool: Sequence[str]) -> str:
    c = difflib.get_close_matches(name, list(pool), n=1, cutoff=0.3)
    return f" (closest: {c[0]!r})" if c else f" (columns: {', '.join(list(pool)[:12])})"


@dataclass
class Split:
    """Chronological rows: train [0, n_train), then the two held-out windows in ``order``;
    one of them may be empty (a single held-out window)."""

    n_train: int
    validation: slice
    test: slice
    n: int

    def as_dict(self) -> dict[str, list[int] | None]:
        def rows(sl: slice) -> list[int] | None:
            return [sl.start, sl.stop - 1] if sl.stop > sl.start else None
        return {"train": [0, self.n_train - 1], "validation": rows(self.validation), "test": rows(self.test)}

    def windows(self) -> list[tuple[str, slice]]:
        """The held-out windows that have rows."""
        return [(w, sl) for w, sl in (("test", self.test), ("validation", self.validation)) if sl.stop > sl.start]


def make_split(n: int, split: Mapping[str, Any] | None = None) -> Split:
    """Cut ``n`` rows: ``train``/``validation``/``test`` as fractions (sum 1; one held-out
    fraction may be 0) or first rows (``train_end``, ``held_out_boundary``; a boundary equal
    to ``n`` leaves the second window empty); ``order`` says which held-out window comes first."""
    s = dict(DEFAULT_SPLIT)
    s.update(split or {})
    bad = sorted(set(s) - {"train", "validation", "test", "order", "train_end", "held_out_boundary"})
    if bad:
        raise SpecError(f"split: {bad[0]!r} is not a key (allowed: train, validation, test, order, train_end, "
                        f"held_out_boundary)")
    order = list(s["order"])
    if sorted(order) != ["test", "validation"]:
        raise SpecError(f"split.order: {order!r} must name 'validation' and 'test' once each")
    if "train_end" in s:
        a, b = int(s["train_end"]), int(s.get("held_out_boundary", (int(s["train_end"]) + n) // 2))
    else:
        fr = [float(s[k]) for k in ("train", "validation", "test")]
        if not (0 < fr[0] < 1) or any(not (0 <= f < 1) for f in fr[1:]) or fr[1] + fr[2] <= 0 \
                or abs(sum(fr) - 1.0) > 1e-6:
            raise SpecError(f"split: train/validation/test fractions {fr} must sum to 1, train in (0, 1), "
                            "the held-out windows in [0, 1) and not both 0")
        a = int(fr[0] * n)
        b = int((fr[0] + float(s[order[0]])) * n)
        b = a if float(s[order[0]]) == 0 else (n if float(s[order[1]]) == 0 else b)
    if not (0 < a < n and a <= b <= n):
        raise SpecError(f"split: rows {n} cut at {a} / {b}: need 0 < train_end < {n} and "
                        f"train_end <= held_out_boundary <= {n}")
    first, second = slice(a, b), slice(b, n)
    win = dict(zip(order, (first, second)))
    return Split(a, win["validation"], win["test"], n)


@dataclass
class EvaluationData:
    """The recording as every model sees it (temperatures degC, displacements um)."""

    time_s: np.ndarray
    temperatures: np.ndarray                  # N x m
    sensors: list[str]
    inputs: np.ndarray | None                 # N x q or None
    input_names: list[str]
    displacement_um: dict[str, np.ndarray]
    split: Split
    source: str = ""
    notes: list[str] = field(default_factory=list)
    #: several runs laid end to end: per row the run it belongs to, -1 for a row that is not a
    #: reading (a run's rest before it); None: one recording. A change counts only inside one run.
    run_id: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.time_s.size)

    @property
    def channels(self) -> list[str]:
        return list(self.displacement_um)


def load_spec(path: str | pathlib.Path | None) -> dict[str, Any]:
    if path is None:
        return {}
    raw = yaml.safe_load(pathlib.Path(path).read_text(encoding="utf-8-sig")) or {}
    if not isinstance(raw, dict):
        raise SpecError(f"{path}: a spec is a mapping with keys {', '.join(SPEC_KEYS)}")
    return raw


def check_spec(spec: Mapping[str, Any]) -> None:
    for k in spec:
        if k not in SPEC_KEYS:
            raise SpecError(f"spec: {k!r} is not a key{closest(k, SPEC_KEYS)}")


def _select(pool: list[str], patterns: Sequence[str] | None, default: list[str], what: str) -> list[str]:
    if patterns is None:
        return default
    out: list[str] = []
    for p in patterns:
        hits = [c for c in pool if fnmatch.fnmatchcase(c, p)] if any(ch in p for ch in "*?[") else \
            ([p] if p in pool else [])
        if not hits:
            raise SpecError(f"{what}: column {p!r} is not in the recording{closest(p, pool)}")
        out += [h for h in hits if h not in out]
    return out


def _units(spec_units: Mapping[str, str], name: str, table: Mapping, default: str):
    unit = spec_units.get(name, spec_units.get("*" if table is LENGTH_UNITS else "*_temperature", default))
    if unit not in table:
        raise SpecError(f"units.{name}: {unit!r} is not one of {', '.join(table)}")
    return table[unit]


def _filled(x: np.ndarray, name: str, notes: list[str]) -> np.ndarray:
    """Forward-fill NaN of a temperature or input (a failed reading holds the last value)."""
    bad = ~np.isfinite(x)
    if not bad.any():
        return x
    if bad.all():
        raise SpecError(f"column {name!r}: no finite value")
    idx = np.where(bad, 0, np.arange(x.size))
    np.maximum.accumulate(idx, out=idx)
    y = x[idx]
    first = int(np.flatnonzero(~bad)[0])
    y[:first] = x[first]
    notes.append(f"{name}: {int(bad.sum())} missing values held from the previous row")
    return y


def evaluation_data(rec: Recording, spec: Mapping[str, Any], whole: bool = False) -> EvaluationData:
    """Pick columns, convert units, split: the data every model and baseline is run on.
    ``whole``: no split by time (every row a training row): one run of a data set."""
    check_spec(spec)
    pool = list(rec.columns)
    kinds = {c: column_kind(c) for c in pool}
    temps = _select(pool, spec.get("temperatures"), [c for c in pool if kinds[c] == "sensor"], "temperatures")
    disp = _select(pool, spec.get("displacements"), [c for c in pool if kinds[c] == "error"], "displacements")
    taken = set(temps) | set(disp)
    default_inputs = [c for c in pool if kinds[c] == "input" and c not in taken]
    inputs = _select(pool, spec.get("inputs"), default_inputs, "inputs")
    if not temps:
        raise SpecError(f"temperatures: none in {rec.source or 'the recording'} (columns ending in _c, or name them "
                        f"with --temperatures){closest('t1_c', pool)}")
    if not disp:
        raise SpecError(f"displacements: none in {rec.source or 'the recording'} (columns ending in _um or E_*, or "
                        f"name them with --displacements){closest('ch1_um', pool)}")
    both = sorted((set(temps) & set(disp)) | (set(inputs) & taken))
    if both:
        raise SpecError(f"column {both[0]!r} is selected twice (as temperature, displacement or input)")
    units = dict(spec.get("units") or {})
    notes = list(rec.warnings)
    T = []
    for c in temps:
        k, off = _units(units, c, TEMPERATURE_UNITS, "C")
        T.append(_filled(np.asarray(rec.columns[c], float) * k + off, c, notes))
    relative = bool(spec.get("relative_to_first_row", True))
    D = {}
    for c in disp:
        y = np.asarray(rec.columns[c], float) * _units(units, c, LENGTH_UNITS, "um")
        ok = np.flatnonzero(np.isfinite(y))
        if ok.size < 10:
            raise SpecError(f"displacements: column {c!r} has only {ok.size} finite values")
        D[c] = y - y[ok[0]] if relative else y
    U = [_filled(np.asarray(rec.columns[c], float), c, notes) for c in inputs]
    n = rec.time_s.size
    split = Split(n, slice(n, n), slice(n, n), n) if whole else make_split(n, spec.get("split"))
    if split.n_train < 50 and not whole:
        raise SpecError(f"split: {split.n_train} training rows; the walk-forward needs >= 50")
    return EvaluationData(np.asarray(rec.time_s, float), np.column_stack(T), temps,
                          np.column_stack(U) if U else None, inputs, D, split, rec.source, notes)


def load_evaluation_data(path: str | pathlib.Path, spec: Mapping[str, Any] | None = None,
                         map_file: str | None = None, map_flags: Sequence[str] | None = None,
                         whole: bool = False) -> EvaluationData:
    """Read ``path`` with the spec's ``mapping`` (plus ``--map-file`` / ``--map`` flags, which win);
    ``whole``: not split by time (one run of a data set)."""
    spec = dict(spec or {})
    check_spec(spec)
    m = spec.get("mapping") or {}
    mapping = ColumnMapping(columns={str(k): str(v) for k, v in (m.get("columns") or {}).items()},
                            scale={str(k): float(v) for k, v in (m.get("scale") or {}).items()})
    extra = parse_mapping(map_file, list(map_flags or []))
    mapping.columns.update(extra.columns)
    mapping.scale.update(extra.scale)
    topics = {k: spec[k] for k in ("temperatures_topic", "errors_topic") if k in spec}
    period = spec.get("sample_period_s")
    rec = read_real_recording(path, mapping, **topics, sample_period_s=None if period is None else float(period))
    return evaluation_data(rec, spec, whole)


#: FL_THERMAL as one dataset configuration: the authors' chronological 60 % train, then test,
#: then validation (docs/fl_thermal.md). Nothing else about the dataset is special.
FL_THERMAL_SPEC: dict[str, Any] = {
    "name": "FL_THERMAL",
    "temperatures": [f"t{i}_c" for i in range(1, 17)],
    "displacements": [f"ch{i}_um" for i in range(1, 6)],
    "inputs": ["spindle_rpm"],
    "units": {},
    "split": {"train": 0.6, "validation": 0.2, "test": 0.2, "order": ["test", "validation"]},
}


def input_scale(values: np.ndarray) -> float:
    """Scale that keeps a machine input O(1) in features (e.g. rpm -> krpm-like)."""
    s = float(np.nanmax(np.abs(values))) if values.size else 0.0
    return 1.0 if not math.isfinite(s) or s == 0 else 10.0 ** math.floor(math.log10(s))
