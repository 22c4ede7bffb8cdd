"""The lock-step round-trip breakdown of ``bench graph`` (thermal_comp.graph_profile) on
hand-made arrival times."""
import pytest

from thermal_comp.graph_profile import STAGES, ack_breakdown, instant_events, stage_breakdown

PARTS = ["sensors", "model", "bridge"]


def _run(n: int = 4):
    """Instant k at 100 ms steps: temperatures +1 ms, prediction +3, offsets +13, acks
    sensors +2, model +4, bridge +14 (the last), next instant 20 ms after that ack."""
    arrivals, acks = {}, {}
    for k in range(n):
        s, t0 = k * 300_000_000_000, k * 0.034
        arrivals[("twin/sensor_readings", s)] = t0
        arrivals[("temperatures", s)] = t0 + 0.001
        arrivals[("errors/predicted", s)] = t0 + 0.003
        arrivals[("offsets", s)] = t0 + 0.013
        for node, d in zip(PARTS, (0.002, 0.004, 0.014)):
            acks[(node, s)] = t0 + d
    return arrivals, acks


def test_stages_split_the_cycle():
    arrivals, acks = _run()
    events = instant_events(arrivals, acks, PARTS)
    assert len(events) == 3          # the last instant has no next one
    out = stage_breakdown(events)
    assert [name for name, _, _ in STAGES] + ["instant (sum)"] == list(out)
    medians = [out[name]["median_ms"] for name, _, _ in STAGES]
    assert medians == pytest.approx([1.0, 2.0, 10.0, 1.0, 20.0], abs=1e-6)
    assert out["instant (sum)"]["median_ms"] == pytest.approx(34.0)
    assert sum(out[name]["share_pct"] for name, _, _ in STAGES) == pytest.approx(100.0, abs=0.3)


def test_instant_missing_an_ack_is_left_out():
    arrivals, acks = _run()
    del acks[("model", 300_000_000_000)]
    assert 300_000_000_000 not in instant_events(arrivals, acks, PARTS)


def test_ack_breakdown_names_who_holds_the_graph():
    arrivals, acks = _run()
    out = ack_breakdown(arrivals, acks, PARTS)
    assert out["bridge"]["last_pct"] == 100.0 and out["sensors"]["last_pct"] == 0.0
    assert out["model"]["median_ms"] == pytest.approx(4.0)


def test_no_instants_no_figures():
    assert stage_breakdown({}) == {}
