"""A lock-step model waits for the machine state of an instant, within a bound."""
import math

import pytest

from talc_model.loop.instant_inputs import InputsReady, InstantInputs


def test_an_instant_waits_for_its_state_then_steps():
    ii = InstantInputs(max_wait_s=10.0)
    assert ii.ready(0.0, wall_s=100.0) is InputsReady.WAIT          # start-up: no state yet
    assert ii.ready(0.0, wall_s=102.0) is InputsReady.WAIT          # the re-sent instant, still none
    ii.state_arrived(0.0)
    assert ii.ready(0.0, wall_s=102.5) is InputsReady.STEP
    ii.state_arrived(300.0)
    assert ii.ready(300.0, wall_s=103.0) is InputsReady.STEP


def test_an_older_state_does_not_count_for_a_newer_instant():
    ii = InstantInputs(max_wait_s=5.0)
    ii.state_arrived(300.0)
    assert ii.ready(600.0, wall_s=0.0) is InputsReady.WAIT
    assert ii.ready(300.0, wall_s=0.0) is InputsReady.STEP           # a late or repeated instant


def test_the_wait_is_bounded_per_instant():
    ii = InstantInputs(max_wait_s=5.0)
    assert ii.ready(600.0, wall_s=0.0) is InputsReady.WAIT
    assert ii.ready(600.0, wall_s=4.9) is InputsReady.WAIT
    assert ii.ready(600.0, wall_s=5.0) is InputsReady.STEP_HELD
    # the next instant gets its own full wait
    assert ii.ready(900.0, wall_s=6.0) is InputsReady.WAIT
    assert ii.ready(900.0, wall_s=10.9) is InputsReady.WAIT
    assert ii.ready(900.0, wall_s=11.0) is InputsReady.STEP_HELD


def test_a_zero_wait_never_holds_an_instant_and_bad_stamps_are_ignored():
    ii = InstantInputs(max_wait_s=0.0)
    assert ii.ready(0.0, wall_s=0.0) is InputsReady.STEP_HELD
    ii.state_arrived(math.nan)
    ii.state_arrived(math.inf)
    assert ii.state_t == -math.inf


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf])
def test_a_bad_wait_is_refused_naming_it(bad):
    with pytest.raises(ValueError, match="max_wait_s"):
        InstantInputs(bad)
