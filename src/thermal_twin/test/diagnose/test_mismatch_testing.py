"""The held-out F test and Holm's correction of the mismatch finder."""
from __future__ import annotations

import numpy as np

from thermal_twin.diagnose.significance import holdout_p_value, holm_reject


def test_p_value_falls_with_the_improvement_and_the_effective_samples():
    assert holdout_p_value(100.0, 100.0, 1, 50) == 1.0
    assert holdout_p_value(100.0, 120.0, 1, 50) == 1.0
    weak, strong = holdout_p_value(100.0, 90.0, 1, 50), holdout_p_value(100.0, 20.0, 1, 50)
    assert strong < 1e-6 < weak < 0.2
    # the same improvement seen on fewer independent samples is weaker evidence
    assert holdout_p_value(100.0, 60.0, 2, 12) > holdout_p_value(100.0, 60.0, 2, 200)


def test_holm_counts_every_hypothesis_tried():
    p = [0.0005, 0.02, 0.5]
    assert holm_reject(p, 3) == [True, True, False]      # 0.0005 <= .05/3, 0.02 <= .05/2
    assert holm_reject(p, 60) == [True, False, False]    # 0.0005 <= .05/60, 0.02 > .05/59
    assert holm_reject([0.01], 60) == [False]            # 0.01 > .05/60
    assert holm_reject([], 10) == []


def test_holm_controls_false_adoptions_under_the_null():
    rng = np.random.default_rng(0)
    fam = sum(any(holm_reject(list(rng.random(40)), 40)) for _ in range(2000))
    assert fam / 2000 < 0.07                             # family-wise error near 5 %, not 1 - 0.95^40
