"""Splits of a data set by run: which runs train the models and which are held out.

One grammar for every command that takes several recordings (``evaluate`` and ``calibrate``
``--runs-split``); it lives here, beside the run sources, because thermal_twin cannot import
thermal_eval. ``how``:

- ``TRAIN,VAL,TEST`` fractions of the runs (default ``0.6,0.2,0.2``), in date order when every
  run has a date, else in the order given: the last runs are held out (tomorrow's run);
- ``loro``: leave one run out, one fold per run;
- ``by:FIELD``: leave one group out by a metadata field (``by:unit``, ``by:programme``,
  ``by:hall_setpoint_c``), one fold per value;
- ``by:FIELD=VALUE[,VALUE]``: the runs with that value are the test runs (``by:unit=U3``);
- ``test=NAME[,NAME]`` (and optionally ``;validation=NAME,...``): named runs.

Every fold keeps at least one training run and one held-out run. Pure.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from thermal_comp_common.recording_sources import META_FIELDS, DatasetError, RunEntry

DEFAULT_RUN_SPLIT = "0.6,0.2,0.2"


@dataclass(frozen=True)
class RunFold:
    """Run indices: ``train`` fit the models; ``validation`` and ``test`` are scored, each run alone."""

    name: str
    train: tuple[int, ...]
    validation: tuple[int, ...]
    test: tuple[int, ...]

    def held_out(self) -> list[tuple[str, int]]:
        return [("validation", i) for i in self.validation] + [("test", i) for i in self.test]


def _ordered(runs: Sequence[RunEntry]) -> list[int]:
    idx = list(range(len(runs)))
    if all(r.date for r in runs):
        idx.sort(key=lambda i: runs[i].date)
    return idx


def _fractions(runs: Sequence[RunEntry], how: str) -> list[RunFold]:
    try:
        fr = [float(x) for x in how.split(",")]
    except ValueError:
        raise DatasetError(f"runs split {how!r}: expected TRAIN,VAL,TEST fractions, loro, by:FIELD[=VALUE] or "
                           "test=NAME,...") from None
    if len(fr) != 3 or any(not 0 <= f <= 1 for f in fr) or abs(sum(fr) - 1) > 1e-6 or fr[0] == 0:
        raise DatasetError(f"runs split {how!r}: three fractions in [0, 1] summing to 1, train > 0")
    n = len(runs)
    n_val, n_test = int(round(fr[1] * n)), int(round(fr[2] * n))
    if fr[1] + fr[2] > 0 and n_val + n_test == 0:
        n_test = 1
    n_train = n - n_val - n_test
    if n_train < 1 or n_val + n_test < 1:
        raise DatasetError(f"runs split {how!r}: {n} runs give {n_train} training and {n_val + n_test} held-out "
                           "runs; need at least one of each")
    order = _ordered(runs)
    return [RunFold(how, tuple(order[:n_train]), tuple(order[n_train:n_train + n_val]),
                    tuple(order[n_train + n_val:]))]


def _by(runs: Sequence[RunEntry], spec: str) -> list[RunFold]:
    key, _, values = spec.partition("=")
    key = key.strip()
    if key not in META_FIELDS and not any(key in r.extra for r in runs):
        raise DatasetError(f"runs split 'by:{spec}': field {key!r} is not run metadata ({', '.join(META_FIELDS)} "
                           "or a manifest column)")
    groups: dict[str, list[int]] = {}
    for i, r in enumerate(runs):
        groups.setdefault(r.meta(key), []).append(i)
    if values:
        wanted = [v.strip() for v in values.split(",")]
        bad = [v for v in wanted if v not in groups]
        if bad:
            raise DatasetError(f"runs split 'by:{spec}': no run has {key} = {bad[0]!r} (values: "
                               f"{', '.join(sorted(groups))})")
        test = tuple(i for v in wanted for i in groups[v])
        folds = [RunFold(f"{key}={values}", tuple(i for i in range(len(runs)) if i not in test), (), test)]
    else:
        if len(groups) < 2:
            raise DatasetError(f"runs split 'by:{key}': every run has {key} = {next(iter(groups))!r}; "
                               "leaving a group out needs two values")
        folds = [RunFold(f"{key}={v}", tuple(i for i in range(len(runs)) if i not in g), (), tuple(g))
                 for v, g in groups.items()]
    for f in folds:
        if not f.train:
            raise DatasetError(f"runs split 'by:{spec}': fold {f.name} leaves no training run")
    return folds


def _named(runs: Sequence[RunEntry], how: str) -> list[RunFold]:
    names = {r.name: i for i, r in enumerate(runs)}
    picked: dict[str, tuple[int, ...]] = {"test": (), "validation": ()}
    for part in how.split(";"):
        key, _, vals = part.partition("=")
        key = key.strip()
        if key not in picked:
            raise DatasetError(f"runs split {how!r}: {key!r} is not 'test' or 'validation'")
        bad = [v.strip() for v in vals.split(",") if v.strip() not in names]
        if bad:
            raise DatasetError(f"runs split {how!r}: no run named {bad[0]!r} (runs: {', '.join(list(names)[:12])})")
        picked[key] = tuple(names[v.strip()] for v in vals.split(","))
    held = set(picked["test"]) | set(picked["validation"])
    train = tuple(i for i in range(len(runs)) if i not in held)
    if not train or not held:
        raise DatasetError(f"runs split {how!r}: need at least one training run and one held-out run")
    return [RunFold(how, train, picked["validation"], picked["test"])]


def run_splits(runs: Sequence[RunEntry], how: str | None = None) -> list[RunFold]:
    """The folds ``how`` names (module docstring); refused with a one-line reason."""
    how = (how or DEFAULT_RUN_SPLIT).strip()
    if len(runs) < 2:
        raise DatasetError(f"runs split {how!r}: {len(runs)} run; splitting by run needs at least two "
                           "(one recording is split in time: --split)")
    if how == "loro":
        return [RunFold(f"without {r.name}", tuple(j for j in range(len(runs)) if j != i), (), (i,))
                for i, r in enumerate(runs)]
    if how.startswith("by:"):
        return _by(runs, how[3:])
    if how.startswith(("test=", "validation=")):
        return _named(runs, how)
    return _fractions(runs, how)
