"""The load-change rule (talc_model.open_loop.load_probing): steps of the machine inputs, and a
probing D minutes after each, drawn from a token bucket."""
from __future__ import annotations

import numpy as np
import pytest

from talc_model.open_loop.load_probing import LoadProbingError, bucket_schedule, input_steps, within_bucket_bound


def test_input_steps_are_the_level_changes_of_any_input_column():
    load = np.repeat([500.0, 2000.0, 800.0, 3000.0, 1200.0, 2600.0, 600.0, 2200.0], 120)   # a step every 120 rows
    assert input_steps(load, 540).tolist() == list(range(120, 960, 120))
    ramp = np.arange(101.0)                         # a slow ramp steps each time it has moved over 10 % of its range
    assert input_steps(ramp, 101).tolist() == list(range(11, 101, 11))
    flat = np.column_stack([np.full(50, 3.0), np.r_[np.zeros(20), np.full(30, 5.0)]])
    assert input_steps(flat, 10).tolist() == []       # constant on the training rows: no steps
    assert input_steps(flat, 30).tolist() == [20]
    assert input_steps(None, 10).size == 0
    with pytest.raises(LoadProbingError, match="fraction"):
        input_steps(flat, 30, fraction=0.0)


def test_the_bucket_never_exceeds_its_bound():
    rng = np.random.default_rng(3)
    t = np.arange(3000) * 60.0
    steps = np.sort(rng.choice(np.arange(1, 3000), 200, replace=False))   # a busy machine
    for rate, depth, delay, credit in ((1.0, 1.0, 5.0, 1.0), (1.0, 3.0, 0.0, 1.0), (0.5, 2.0, 10.0, 1.0),
                                       (2.0, 4.0, 20.0, 1.0), (1.0, 2.0, 5.0, 0.0)):
        clock0 = t[99] + 600.0
        rows, asked, load = bucket_schedule(t, 100, clock0, steps, rate, depth, 60.0 * delay, 60.0, 3600.0, 95.0,
                                            lambda r, last: True, credit)   # the model always asks
        assert rows and set(load) <= set(asked) <= set(rows) and rows == sorted(rows)
        assert t[rows[0]] >= clock0 + (0.0 if credit else 3600.0 / rate)
        assert within_bucket_bound(t, rows, clock0, rate, credit)
        assert len(rows) <= credit + rate * (t[-1] - clock0) / 3600.0
        assert len(rows) >= rate * (t[-1] - clock0) / 3600.0 - depth   # the bucket is spent, not hoarded
    assert not within_bucket_bound(t, [200, 201, 202], t[199], 1.0)
    with pytest.raises(LoadProbingError, match="depth"):
        bucket_schedule(t, 100, t[99], steps, 1.0, 0.5, 0.0, 60.0, 3600.0, 95.0, lambda r, last: True)
    with pytest.raises(LoadProbingError, match="credit"):
        bucket_schedule(t, 100, t[99], steps, 1.0, 2.0, 0.0, 60.0, 3600.0, 95.0, lambda r, last: True, 2.0)


def test_a_step_makes_a_probing_due_d_minutes_later_and_a_quiet_model_is_not_probed():
    t = np.arange(900) * 60.0
    rows, asked, load = bucket_schedule(t, 540, t[539], np.array([120, 600, 720, 840]), 1.0, 2.0, 600.0, 600.0,
                                        360000.0, 95.0, lambda r, last: False)
    assert rows == asked == load == [610, 730, 850]    # each step + 10 min (60-s rows); the step at 120 is long past
    assert bucket_schedule(t, 540, t[539], np.zeros(0, int), 1.0, 2.0, 600.0, 600.0, 360000.0, 95.0,
                           lambda r, last: False)[0] == []
