"""single_thread_blas: one BLAS thread (with ``openmp``, every native pool) inside, the previous
limits back outside; the library scan is reused until modules were imported since."""
from __future__ import annotations

import sys
import types

import numpy as np  # noqa: F401  loads numpy's BLAS
import threadpoolctl
from threadpoolctl import threadpool_info, threadpool_limits

from thermal_comp_common.runtime.blas_threads import single_thread_blas


def _threads(user_api: str | None = None) -> list[int]:
    return [p["num_threads"] for p in threadpool_info() if user_api is None or p["user_api"] == user_api]


def test_blas_runs_on_one_thread_inside_and_as_before_outside():
    with threadpool_limits(limits=2):
        before = _threads()
        with single_thread_blas():
            assert _threads("blas") and all(n == 1 for n in _threads("blas"))
        assert _threads() == before


def test_with_openmp_every_pool_runs_on_one_thread():
    with threadpool_limits(limits=2):
        before = _threads()
        with single_thread_blas(openmp=True):
            assert _threads() and all(n == 1 for n in _threads())
        assert _threads() == before


def test_a_plain_call_holds_until_restored():
    with threadpool_limits(limits=2, user_api="blas"):
        limiter = single_thread_blas()
        assert all(n == 1 for n in _threads("blas"))
        limiter.restore_original_limits()
        assert all(n == 2 for n in _threads("blas"))


def test_the_scan_is_redone_only_after_an_import(monkeypatch):
    scans = []

    class CountingController(threadpoolctl.ThreadpoolController):
        def __init__(self):
            scans.append(1)
            super().__init__()

    monkeypatch.setattr(threadpoolctl, "ThreadpoolController", CountingController)
    monkeypatch.setitem(sys.modules, "_blas_threads_probe_a", types.ModuleType("a"))
    with single_thread_blas():
        pass
    with single_thread_blas():
        pass
    assert len(scans) == 1
    monkeypatch.setitem(sys.modules, "_blas_threads_probe_b", types.ModuleType("b"))
    with single_thread_blas():
        pass
    assert len(scans) == 2
