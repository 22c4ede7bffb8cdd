"""thermal_eval.replay.prior_cases: a case's prior never sees the case, and the residual locator."""
import numpy as np
import pytest

from thermal_eval.replay import prior_cases
@pytest.mark.parametrize("case", prior_cases.CASES)
def test_the_prior_of_a_case_never_trains_on_it(case):
    train = prior_cases.prior_training(case)
    assert case not in [s for s, _ in train]
    assert len(train) >= 4 and all(seed >= 101 for _, seed in train)   # the runs use seed 0


def test_error_location_finds_the_largest_residuals_an_hour_apart():
    class Result:
        time_s = np.arange(0.0, 20 * 3600.0, 300.0)
        residual = {"E_X0C": np.zeros(240)}
        phase = ["compensation"] * 240
    r = Result()
    r.residual["E_X0C"][[24, 25, 120]] = [3.0, 2.9, -5.0]     # 2.9 is 5 min after 3.0: same event
    peaks = prior_cases.error_location(r, ["E_X0C"], top=2)[0]["peaks"]
    assert [(h, v) for h, v, _ in peaks] == [(10.0, 5.0), (2.0, 3.0)]


def test_given_training_programmes_replace_the_default_and_still_leave_the_case_out():
    train = prior_cases.prior_training("load-case-D", ["load-case-A", "load-case-D", "type-mwf-hall-phases",
                                                       "load-case-C"])
    assert train == [("load-case-A", 101), ("type-mwf-hall-phases", 102), ("load-case-C", 103)]


def test_unknown_training_programme_is_one_clear_error(capsys):
    assert prior_cases.main(["--training", "load-case-A,no-such-programme,load-case-C"]) == 2
    assert "no-such-programme" in capsys.readouterr().err
