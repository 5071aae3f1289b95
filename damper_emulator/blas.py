"""The BLAS threads the fits run with: one, whatever the machine.

A fit's path (scipy's least squares, its Jacobian's products and factorisations) can follow
the last bits of its sums, and threaded BLAS splits a sum by thread: the same data fitted
with two BLAS threads and with one can end in different local minima of a diagnosis's
joint fits, and so in different answers (docs/diagnose.md, "Cost and parallelism").  The
identification and the diagnosis therefore run their BLAS on :data:`FIT_BLAS_THREADS`
threads (:func:`one_blas_thread`), so that a result does not depend on the machine's core
count or on the caller's thread settings.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

from threadpoolctl import threadpool_limits

__all__ = ["FIT_BLAS_THREADS", "one_blas_thread"]

#: BLAS threads the identification and each fit of a diagnosis run with.  A diagnosis's
#: fits are the parallel work, one task per core; OpenBLAS would otherwise start a pool
#: of one thread per core in every worker, and those threads (which spin before they
#: sleep) compete with the other worker's fit: with two processes on two cores every task
#: runs about 1.4× longer than alone; with one BLAS thread per task the diagnosis takes
#: about a third less (benchmarks/diagnose_bench.py).  Dask's nanny sets the same for its
#: workers (``OPENBLAS_NUM_THREADS=1``, ``distributed.nanny.pre-spawn-environ``).  One
#: thread also keeps the sums independent of the machine's core count (module docstring).
FIT_BLAS_THREADS = 1

_P = ParamSpec("_P")
_R = TypeVar("_R")


def one_blas_thread(fn: Callable[_P, _R]) -> Callable[_P, _R]:
    """``fn`` run with :data:`FIT_BLAS_THREADS` BLAS threads, the caller's given back
    after (``identify``; each fit task of a diagnosis, and a diagnosis's own process: its
    refits beside the Jacobian's threads and the pool's fits)."""
    @functools.wraps(fn)
    def limited(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        with threadpool_limits(limits=FIT_BLAS_THREADS, user_api="blas"):
            return fn(*args, **kwargs)
    return limited
