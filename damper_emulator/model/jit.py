"""The one compilation setting of the physics kernels.

numba, cached on disk, with the fast-math flags that reorder and contract arithmetic and use
approximate library functions, but *not* ``nnan``/``ninf``: the kernels test for NaN and
infinity (bad input must be caught, never propagated), which those two flags would let the
compiler delete.  With these flags the batch simulation runs about 25 % faster
(benchmarks/model_bench.py); the accuracy tests are unaffected.
"""

from __future__ import annotations

from numba import njit

FASTMATH_FLAGS = frozenset({"nsz", "arcp", "contract", "afn", "reassoc"})

#: Decorator for every compiled physics kernel.
kernel = njit(cache=True, fastmath=set(FASTMATH_FLAGS))
