"""The online learner's schedule: every H hours of model time from the first instant, on demand,
one learning at a time, missed due times collapsed into one."""
import math

import pytest

from talc_model.online.schedule import LearnSchedule

H = 3600.0


def test_due_every_h_hours_from_the_first_instant():
    s = LearnSchedule(24.0)
    s.observe(1000.0)
    assert s.take(busy=False) == ""
    s.observe(1000.0 + 24 * H - 1)
    assert s.take(busy=False) == ""
    s.observe(1000.0 + 24 * H)
    assert s.take(busy=False).startswith("schedule")
    assert s.take(busy=False) == ""                       # served once
    assert s.next_due == 1000.0 + 48 * H
    assert s.hours(1000.0 + 30 * H) == pytest.approx(30.0)


def test_due_times_passed_while_busy_collapse_into_one_learning():
    s = LearnSchedule(1.0)
    s.observe(0.0)
    s.observe(5.5 * H)
    assert s.take(busy=True) == ""                        # kept while a learning runs
    assert s.take(busy=False).startswith("schedule")
    assert s.take(busy=False) == ""
    assert s.next_due == 6 * H


def test_on_demand_only_and_a_request():
    s = LearnSchedule(0.0)
    s.observe(0.0)
    s.observe(1e9)
    assert s.take(busy=False) == "" and math.isinf(s.next_due)
    s.request()
    assert s.take(busy=True) == ""
    assert s.take(busy=False) == "on demand"


def test_nothing_before_the_first_instant_and_a_bad_period_is_refused():
    s = LearnSchedule(1.0)
    s.request()
    assert s.take(busy=False) == ""
    with pytest.raises(ValueError, match="learn_every_h"):
        LearnSchedule(-1.0)
