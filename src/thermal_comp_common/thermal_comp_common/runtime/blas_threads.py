"""One thread for BLAS (and, on request, OpenMP) around many small dense problems.

Identification, the twin's matrix products and k-means solve hundreds of tiny problems: extra
BLAS/OpenMP threads gain nothing there and, on a busy or shared machine, only spin against each
other and against other processes. The results do not depend on the thread count.

Scanning the loaded native libraries takes a few ms and a replay enters the limit hundreds of
times, so the scan is kept and redone only when modules were imported since (an import may have
loaded another BLAS or OpenMP library).
"""
from __future__ import annotations

import sys

_SCAN: list = []   # [(len(sys.modules) at the scan, ThreadpoolController)]


def single_thread_blas(*, openmp: bool = False):
    """Limit BLAS (with ``openmp``, every native thread pool: BLAS and OpenMP) to one thread.

    As a context manager the previous limits come back on exit; as a plain call the limit holds
    until the returned limiter's ``restore_original_limits()`` (or for the process)."""
    from threadpoolctl import ThreadpoolController   # only where a limit is taken: keeps this package's import light
    n_modules = len(sys.modules)
    if not _SCAN or _SCAN[0][0] != n_modules:
        _SCAN[:] = [(n_modules, ThreadpoolController())]
    return _SCAN[0][1].limit(limits=1, user_api=None if openmp else "blas")
