"""One BLAS thread for the many small least-squares problems of identification.

Hundreds of tiny solves are 10-100x slower with a multi-threaded BLAS on a busy machine, so
order selection and TALC's phase logic run them single-threaded. ``threadpoolctl``'s
``threadpool_limits`` scans the loaded libraries on every call (about 5 ms); a replay enters
the limit hundreds of times, so the controller is built once per process and reused.
"""
from __future__ import annotations

from contextlib import AbstractContextManager

_CONTROLLER = None


def single_thread_blas() -> AbstractContextManager:
    """Context manager limiting BLAS to one thread (restores the previous limits on exit)."""
    global _CONTROLLER
    if _CONTROLLER is None:
        from threadpoolctl import ThreadpoolController
        _CONTROLLER = ThreadpoolController()
    return _CONTROLLER.limit(limits=1, user_api="blas")
