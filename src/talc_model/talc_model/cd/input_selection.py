"""Input-variable selection for characteristic diagrams [003 §4]: the forward heuristic
(:func:`forward_selection`) and the stability index (:func:`stability_index`,
:func:`stability_selection`). No rclpy here.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.spatial.distance import pdist
from thermal_comp_common.metrics import rmse

from talc_model.cd.diagram import CharacteristicDiagram, CharacteristicDiagramError, as_2d


@dataclass
class SelectionStep:
    subset: tuple[int, ...]
    score: float


def _holdout_split(k: int, test_fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    perm = rng.permutation(k)
    n_test = max(1, int(round(test_fraction * k)))
    return perm[n_test:], perm[:n_test]


def forward_selection(m, y, *, max_inputs: int = 4, make_cd: Callable[[], CharacteristicDiagram] | None = None,
                      test_fraction: float = 0.2, seed: int = 0,
                      min_relative_gain: float = 0.0,
                      split: tuple[np.ndarray, np.ndarray] | None = None) -> list[SelectionStep]:
    """Sequential forward heuristic (variant 1 of [003 §4]).

    At each size L every free candidate is added to the previous best subset, a CD with the
    same settings is fitted and scored; the best becomes S_L. The paper leaves the norm and
    "tested using training data" open; we score by the RMSE on a fixed random hold-out part
    of the data (``test_fraction``, ``seed``), which penalises over-fitting grids. Stops early
    when the best score improves by less than ``min_relative_gain``. ``split`` = (train rows,
    test rows) replaces the random hold-out (a prior holds out a whole load programme).
    Returns the best subset (column indices) and its score for each size.
    """
    m = as_2d(m, "m")
    y = np.asarray(y, dtype=float).ravel()
    if y.shape[0] != m.shape[0]:
        raise CharacteristicDiagramError(f"y: {y.shape[0]} values for {m.shape[0]} samples")
    make_cd = make_cd or (lambda: CharacteristicDiagram(n_intervals=4, smoothing=1e-4))
    train, test = split if split is not None else _holdout_split(m.shape[0], test_fraction, seed)
    chosen: list[int] = []
    steps: list[SelectionStep] = []
    for _ in range(min(max_inputs, m.shape[1])):
        best: SelectionStep | None = None
        for p in range(m.shape[1]):
            if p in chosen:
                continue
            cols = chosen + [p]
            cd = make_cd().fit(m[np.ix_(train, cols)], y[train])
            score = rmse(cd.predict(m[np.ix_(test, cols)]), y[test])
            if best is None or score < best.score:
                best = SelectionStep(tuple(cols), score)
        assert best is not None
        if steps and not best.score < steps[-1].score * (1.0 - min_relative_gain):
            break
        steps.append(best)
        chosen = list(best.subset)
    return steps


class StabilityIndex:
    """The stability analysis of [003 §4 (d)] over a candidate matrix M (K x P) and output y.

    Columns are normalised to [0, 1]; for every pair of samples (a, b) the per-variable input
    distance |m_a - m_b| and the output distance |y_a - y_b| are kept (pairs in chunks of the
    ``scipy.spatial.distance.pdist`` order). For a subset S:

    * ``variant="printed"`` (eq. 3 as printed): i^S = sum (1 - prod_{p in S} |dm_p|) |dy|;
    * ``variant="closeness"`` (default): i^S = sum prod_{p in S} (1 - |dm_p|) |dy|, i.e. a pair
      counts as close only when it is close in *every* selected input - what the paper's prose
      says the product should describe. Both are lower-is-better and comparable only between
      subsets of the same size (the benchmark measures how often each finds the true inputs).

    ``max_samples`` subsamples the rows (fixed seed) to bound the K^2/2 pair memory.
    """

    def __init__(self, m, y, *, variant: str = "closeness", max_samples: int = 400, seed: int = 0):
        if variant not in ("closeness", "printed"):
            raise CharacteristicDiagramError(f"variant: must be 'closeness' or 'printed', got {variant!r}")
        m = as_2d(m, "m")
        y = np.asarray(y, dtype=float).ravel()
        if y.shape[0] != m.shape[0]:
            raise CharacteristicDiagramError(f"y: {y.shape[0]} values for {m.shape[0]} samples")
        ok = np.all(np.isfinite(m), axis=1) & np.isfinite(y)
        m, y = m[ok], y[ok]
        if m.shape[0] < 3:
            raise CharacteristicDiagramError(f"m: stability analysis needs >= 3 finite samples, got {m.shape[0]}")
        if m.shape[0] > max_samples:
            keep = np.sort(np.random.default_rng(seed).choice(m.shape[0], max_samples, replace=False))
            m, y = m[keep], y[keep]
        span = m.max(axis=0) - m.min(axis=0)
        mn = (m - m.min(axis=0)) / np.where(span > 0, span, 1.0)
        self.variant = variant
        self.n_candidates = m.shape[1]
        self.dy = pdist(y[:, None], "cityblock").astype(np.float32)
        dm = np.stack([pdist(mn[:, [p]], "cityblock") for p in range(m.shape[1])]).astype(np.float32)
        # factor per variable whose product over S gives the pair weight
        self.factor = dm if variant == "printed" else (1.0 - dm)

    def index(self, subset: Sequence[int]) -> float:
        prod = np.prod(self.factor[list(subset)], axis=0)
        weight = (1.0 - prod) if self.variant == "printed" else prod
        return float(weight @ self.dy)

    def best_of_size(self, size: int, candidates: Sequence[Sequence[int]] | None = None) -> SelectionStep:
        subsets = candidates if candidates is not None else itertools.combinations(range(self.n_candidates), size)
        best: SelectionStep | None = None
        for s in subsets:
            score = self.index(s)
            if best is None or score < best.score:
                best = SelectionStep(tuple(sorted(s)), score)
        if best is None:
            raise CharacteristicDiagramError(f"size: no candidate subset of size {size}")
        return best


def stability_index(m, y, subset: Sequence[int], variant: str = "closeness") -> float:
    """The instability index i^S of one subset (lower = more suitable); see :class:`StabilityIndex`."""
    return StabilityIndex(m, y, variant=variant).index(subset)


def stability_selection(m, y, *, max_inputs: int = 4, exhaustive_up_to: int = 3, variant: str = "closeness",
                        max_samples: int = 400, seed: int = 0) -> list[SelectionStep]:
    """Best subset per size by the stability index, searched as in [003 §5]: all combinations
    up to ``exhaustive_up_to`` inputs, then from the previous optimum remove one variable and
    add two (the removed one may come back: the paper does not forbid it). The index is
    comparable only within one size; choose the size by CD test error."""
    si = StabilityIndex(m, y, variant=variant, max_samples=max_samples, seed=seed)
    p = si.n_candidates
    steps: list[SelectionStep] = []
    for size in range(1, min(max_inputs, p) + 1):
        if size <= exhaustive_up_to or not steps:
            steps.append(si.best_of_size(size))
            continue
        prev = steps[-1].subset
        cands = set()
        for drop in prev:
            kept = [v for v in prev if v != drop]
            free = [v for v in range(p) if v not in kept]
            for pair in itertools.combinations(free, 2):
                cands.add(tuple(sorted(kept + list(pair))))
        steps.append(si.best_of_size(size, sorted(cands)))
    return steps
