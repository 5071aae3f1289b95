"""The one compilation setting of the compiled kernels, and where their machine code is
cached.

**Flags.**  numba, cached on disk, with the fast-math flags that reorder and contract
arithmetic and use approximate library functions, but *not* ``nnan``/``ninf``: the kernels
test for NaN and infinity (bad input must be caught, never propagated), which those two flags
would let the compiler delete.  With these flags the batch simulation runs about 25 % faster
(benchmarks/model_bench.py); the accuracy tests are unaffected.  They are compiled
without numba's reference-counting runtime (see :data:`_physics`).

**Cache location.**  Not the source tree: the user's cache directory,
``$XDG_CACHE_HOME/damper-hil`` (default ``~/.cache/damper-hil``), or ``$NUMBA_CACHE_DIR``
when that is set (numba's own variable; the tests use it for a cold start).  Inside it the
kernels of one version of the sources live in ``kernels-<key>``, where ``key`` hashes every
Python source file of the packages that define or feed kernels (:data:`KEYED_PACKAGES`)
and where the checkout is.
numba's own index notices a change of the file that *defines* a kernel, but not of a kernel
it calls from another file, nor of a module-level constant it froze in at compile time
(e.g. the ride loop calling :func:`damper_emulator.model.step.step`): with the key,
any change of those sources gives a new, empty cache directory, so a stale kernel is never
loaded.  Directories of other keys unused for :data:`PRUNE_AFTER_DAYS` days are removed.

**Compile accounting.**  Every kernel made with :data:`kernel` or :func:`plain_kernel` is
registered; :func:`compiled_signatures` counts their compiled specialisations, so a
real-time node can check that nothing was compiled after it said it was ready (a compile
inside a 1 kHz loop stalls it for seconds).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba
from numba import njit

FASTMATH_FLAGS = frozenset({"nsz", "arcp", "contract", "afn", "reassoc"})

#: Packages (directories next to this package) whose sources make up the cache key.
KEYED_PACKAGES = ("damper_emulator", "ride_sim")
#: Cache directories of other source versions are removed after this long unused [days]
#: (a few checkouts of different versions can share one user cache meanwhile).
PRUNE_AFTER_DAYS = 14
#: Hex digits of the source hash in the directory name (64 bits: no accidental collision).
KEY_DIGITS = 16
#: Prefix of the per-source-version cache directories.
CACHE_PREFIX = "kernels-"


def _source_root() -> Path:
    return Path(__file__).resolve().parents[2]


def source_key(root: Path | None = None) -> str:
    """Hash of every ``.py`` file of :data:`KEYED_PACKAGES` under ``root`` (path and bytes),
    with numba's version, the fast-math flags and where ``root`` is (numba indexes its
    cache by the source file's path: a checkout elsewhere has none of these kernels, and a
    warm-up's mark, ``damper_hil.warm``, must not speak for it)."""
    root = _source_root() if root is None else root
    h = hashlib.sha256(f"numba {numba.__version__} {sorted(FASTMATH_FLAGS)} "
                       f"{root.resolve()}".encode())
    for pkg in KEYED_PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            h.update(str(path.relative_to(root)).encode() + b"\0")
            h.update(path.read_bytes())
    return h.hexdigest()[:KEY_DIGITS]


def cache_base() -> Path:
    """``$NUMBA_CACHE_DIR``, else ``$XDG_CACHE_HOME/damper-hil``, else
    ``~/.cache/damper-hil``."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "damper-hil"


def _prune(base: Path, keep: Path) -> None:
    cutoff = time.time() - PRUNE_AFTER_DAYS * 86400.0
    try:
        siblings = list(base.glob(CACHE_PREFIX + "*"))
    except OSError:
        return
    for d in siblings:
        try:
            if d != keep and d.is_dir() and d.stat().st_mtime < cutoff:
                shutil.rmtree(d, ignore_errors=True)
        except OSError:
            pass


def _configure_cache() -> Path:
    directory = cache_base() / f"{CACHE_PREFIX}{source_key()}"
    try:
        directory.mkdir(parents=True, exist_ok=True)
        os.utime(directory)          # in use: keeps it from being pruned
    except OSError:
        pass                         # numba falls back to no caching with a warning
    _prune(directory.parent, directory)
    # numba picks the locator when a kernel is decorated: this runs before any is
    # (numba.config sets its options as module globals at run time: no attribute to type)
    numba.config.CACHE_DIR = str(directory)  # type: ignore[attr-defined]
    return directory


#: Where this process's kernels are cached (set on import, before any kernel exists).
CACHE_DIR = _configure_cache()

#: a kernel's Python function; the compiled dispatcher is called with its signature
_F = TypeVar("_F", bound=Callable[..., Any])

#: the registered dispatchers (numba's ``CPUDispatcher``, untyped: ``signatures``,
#: ``py_func``)
_KERNELS: list[Any] = []


def _registered(dispatcher: Any) -> Any:
    _KERNELS.append(dispatcher)
    return dispatcher


#: The physics kernels are compiled without numba's runtime (``_nrt=False``): they never
#: allocate (every array comes from the caller), and with the runtime each call between
#: kernels that passes an array (the step's parameter vector, valve tables and state) takes
#: and gives back a reference with an atomic instruction.  Those atomics were most of the
#: profile of a chirp simulation (perf); without them the batch simulation is markedly
#: faster (benchmarks/model_bench.py), forces bit for bit the same.  A kernel that
#: allocated would fail to compile, not misbehave.
# (numba's stubs do not declare the private ``_nrt`` option)
_physics = njit(cache=True, fastmath=set(FASTMATH_FLAGS),
                _nrt=False)  # type: ignore[call-overload]
_plain = njit(cache=True)
#: :data:`_physics` that releases the GIL while it runs: the loops over a whole history,
#: and over a valve table's flows, which a diagnosis's Jacobian runs on several threads at
#: once (a column of a valve's parameter builds its table).  Not the real-time step:
#: a loop thread that let go of the lock at every step could wait for it back behind
#: another thread of its process.
_batch = njit(cache=True, fastmath=set(FASTMATH_FLAGS), _nrt=False,
              nogil=True)  # type: ignore[call-overload]
#: :data:`_physics` inlined into each caller by numba itself (its own IR, before LLVM),
#: and so compiled under the caller's options: a small formula that both the one-design
#: step and a loop over SIMD lanes use, or the body of such a loop (a call left
#: out of line stops the loop's vectorisation).
_inlined = njit(cache=True, fastmath=set(FASTMATH_FLAGS), _nrt=False,
                inline="always")  # type: ignore[call-overload]
#: The loops over SIMD lanes (:mod:`damper_emulator.model.lanes`): :data:`_physics` with
#: numpy's error model, in which a float division by zero gives ±inf or NaN instead of
#: raising.  Under Python's model every division tests its divisor and may raise, and
#: a loop with a possible raise is not vectorised.  Only loops whose divisors cannot be
#: zero use it (each says why).
_lanes = njit(cache=True, fastmath=set(FASTMATH_FLAGS), _nrt=False,
              error_model="numpy")  # type: ignore[call-overload]


def kernel(func: _F) -> _F:
    """Decorator for every compiled physics kernel (fast-math, cached, registered)."""
    return cast(_F, _registered(_physics(func)))


def batch_kernel(func: _F) -> _F:
    """Decorator for a compiled loop over a whole history or a valve table's flows
    (:data:`_batch`: as :func:`kernel`, and the GIL released while it runs)."""
    return cast(_F, _registered(_batch(func)))


def inlined_kernel(func: _F) -> _F:
    """Decorator for a physics kernel that numba inlines into its callers (:data:`_inlined`):
    the body of a loop over SIMD lanes."""
    return cast(_F, _registered(_inlined(func)))


def lane_kernel(func: _F) -> _F:
    """Decorator for a loop over SIMD lanes (:data:`_lanes`: numpy's error model)."""
    return cast(_F, _registered(_lanes(func)))


def plain_kernel(func: _F) -> _F:
    """Decorator for compiled helpers that need exact IEEE arithmetic (byte handling of the
    bag readers): cached and registered, no fast-math."""
    return cast(_F, _registered(_plain(func)))


def compiled_signatures() -> int:
    """Number of compiled specialisations of every registered kernel in this process
    (loaded from the cache or compiled).  It grows only when a kernel meets argument types
    it was not yet specialised for."""
    return sum(len(k.signatures) for k in _KERNELS)


def uncompiled_kernels() -> list[str]:
    """Names of registered kernels with no specialisation yet."""
    return [k.py_func.__qualname__ for k in _KERNELS if not k.signatures]
