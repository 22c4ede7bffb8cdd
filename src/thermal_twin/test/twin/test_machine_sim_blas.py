"""machine_sim runs the twin on one BLAS thread (idle OpenBLAS workers spin on the other core
while the instant's sensors -> model -> bridge path runs) and restores the process's limit when
destroyed; the twin's outputs do not depend on the BLAS thread count (bit-identical)."""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits


def _blas_threads() -> list[int]:
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def _run(threads: int, steps: int) -> np.ndarray:
    from thermal_twin.machine.schema import load_machine
    from thermal_twin.sim.scenario_runner import ScenarioRunner
    from thermal_twin.sim.scenarios import make_timeline
    with threadpool_limits(limits=threads, user_api="blas"):
        m = load_machine("nmv5000")
        r = ScenarioRunner(m, make_timeline(m.name, "talc-178h-dry", seed=0), seed=0)
        out = []
        for k in range(steps):
            out.append(list(r.sensor_readings().values()) + list(r.errors().values()))
            r.step()
            if k % 50 == 7:          # a probing pause: other regimes, other cached step maps
                r.idle(95.0)
                r.resume()
        return np.array(out)


def test_the_twin_is_bit_identical_on_one_or_two_blas_threads():
    assert np.array_equal(_run(1, 300), _run(2, 300))


@pytest.mark.ros
def test_machine_sim_holds_blas_to_one_thread_while_it_lives(ros_context):
    from thermal_twin.machine_sim_node import MachineSimNode
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        node = MachineSimNode(context=ros_context)
        try:
            assert _blas_threads() and all(n == 1 for n in _blas_threads())
        finally:
            node.destroy_node()
        assert _blas_threads() == before
