"""Load or compile the kernels a first run needs, once, at install.

``make``'s install step runs ``python -m damper_hil.warm``: numba's on-disk cache
(:mod:`damper_emulator.model.jit`: ``$NUMBA_CACHE_DIR``, else the user's cache directory,
one directory per version of the sources) then holds the compiled kernels, and the first
``damper-hil`` command or node loads them instead of compiling for seconds.  What is
warmed is what the nodes warm before they say they are ready: the emulator's core (the
damper's step, every input and fault mode), the ride's session (the quarter car), the bag
reader's helpers, and the batch loops over recorded samples that ``replay`` runs, with
and without a valve command (about 1 s of a first replay's compiling otherwise), and
the damper over a recorded history (``identify``, ``validate``, ``diagnose``, ``dyno``).
A second process warms, beside them, the quarter car's ride and the many-design kernel in
its SIMD lanes and one by one (``tune``; about 11 s of a first run's compiling
otherwise), ``identify``'s valve fits and ``diagnose``'s discovery (:func:`warm_fits`).
Prints one line with the time it took.

**One set of last bits.**  numba's freshly compiled code and the code it loads from its
cache can differ in their last bits (a kernel compiled in the middle of a diagnosis,
among the kernels that run compiled first, is not bit for bit the one a warm-up caches),
and a diagnosis's fits can follow them to another answer.  So a warm-up fills a cache
directory from empty, and marks it (:data:`MARKER`) when it is done; a directory that
some other run filled first is emptied and warmed again.  Every run after it loads the
same kernels.  The process that compiled a kernel runs it as compiled, not as loaded, so
no figure is taken there: :func:`ensure_warmed`, the check for a benchmark or a tool
whose figures must be the install's, warms in another process.
"""

from __future__ import annotations

import contextlib
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from damper_emulator.dyno.measured import MeasuredData
    from damper_emulator.model.compressible import DamperModel

#: The option that makes this module warm the batch kernels (the second process).
BATCH = "--batch"
#: the identification warmed: a chirp this long [s] ...
WARM_CHIRP_S = 4.0
#: ... and force noise of this r.m.s. [N] on its files (a fit of exact data is not the
#: path a measured file takes)
WARM_NOISE_N = 4.0
#: the discovery warmed: the reference temperature [°C] and a zone's width [m]
WARM_TEMPERATURE_C = 25.0
WARM_ZONE_WIDTH_M = 0.01


#: The file a finished warm-up leaves in the kernel cache's directory.
MARKER = "warmed"


def cache_directory() -> Path:
    """This source version's kernel cache (:data:`damper_emulator.model.jit.CACHE_DIR`)."""
    from damper_emulator.model.jit import CACHE_DIR
    return CACHE_DIR


def warmed() -> bool:
    """Whether a warm-up filled this source version's kernel cache (from empty)."""
    return (cache_directory() / MARKER).is_file()


def warm_from_empty() -> float:
    """:func:`warm` into this source version's kernel cache, emptied first where no
    warm-up filled it (module docstring), then marked; returns the seconds it took."""
    directory = cache_directory()
    if not warmed():
        shutil.rmtree(directory, ignore_errors=True)
    # (a directory that cannot be made: numba runs without its cache, unmarked)
    with contextlib.suppress(OSError):
        directory.mkdir(parents=True, exist_ok=True)
    seconds = warm()
    with contextlib.suppress(OSError):
        (directory / MARKER).write_text("filled by python -m damper_hil.warm\n")
    return seconds


def ensure_warmed() -> None:
    """Warm this source version's kernel cache unless a warm-up filled it (for a
    benchmark or tool whose figures must be those of an installed checkout), in another
    process (``python -m damper_hil.warm``, which says how long it took): this one then
    loads every kernel from the cache, as an installed run does.  (Compiled here, the
    kernels would run here as compiled, not as loaded, and their last bits differ: module
    docstring.)"""
    if not warmed():
        subprocess.run([sys.executable, "-m", "damper_hil.warm"], check=True)


def warm() -> float:
    """Exercise the kernels (module docstring), the batch kernels in a second process;
    returns the seconds it took."""
    start = time.monotonic()
    batch = subprocess.Popen([sys.executable, "-m", "damper_hil.warm", BATCH])
    warm_nodes()
    if batch.wait() != 0:
        raise RuntimeError(f"warming the batch kernels failed (status {batch.returncode})")
    return time.monotonic() - start


def warm_batch() -> None:
    """The batch kernels (module docstring)."""
    import numpy as np

    from damper_emulator.model.compressible import DamperModel
    from damper_emulator.model.lanes import LANES
    from ride_sim.dampers import CompressiblePlugin
    from ride_sim.many import simulate_many
    from ride_sim.params import load_quarter_car
    from ride_sim.quarter_car import simulate as ride

    model = DamperModel()
    car = load_quarter_car()
    ride(car, CompressiblePlugin(model), np.zeros(64), 1e-3)
    simulate_many(car, [model] * LANES, np.zeros(64), 1e-3)   # one block of lanes
    simulate_many(car, [model] * 2, np.zeros(64), 1e-3, lanes=False)
    warm_fits(model)


def warm_fits(model: DamperModel) -> None:
    """``identify``'s valve fits (the valve characteristic's derivatives and its
    complex-step specialisations) and ``diagnose``'s discovery (the features of a record,
    a zone's profile, a lag: :func:`warm_discovery`), on a short quasi-static test and
    chirp of ``model``.  Compiled in the first ``identify`` or ``diagnose`` instead, they
    would also give that run other last bits than every later one: numba's freshly
    compiled code and the code it loads from its cache differ there, and a diagnosis can
    follow them."""
    import numpy as np

    from damper_emulator.dyno import protocols
    from damper_emulator.dyno.measured import MeasuredData
    from damper_emulator.identify.pipeline import identify
    from damper_emulator.model.compressible import simulate

    rng = np.random.default_rng(0)
    files = [MeasuredData(t, x, simulate(model, t, x, v).force_n
                          + rng.normal(0.0, WARM_NOISE_N, t.size), v)
             for t, x, v in (protocols.quasi_static(cycles=1),
                             protocols.chirp(duration_s=WARM_CHIRP_S))]
    identify(files[0], files[1], model.cfg)
    warm_discovery(model, files[1])


def warm_discovery(model: DamperModel, data: MeasuredData) -> None:
    """The kernels of ``diagnose``'s discovery (stage 5), through its own calls on ``data``:
    a record's features under ``model``, at a second sign width, a zone's profile and a
    lag."""
    import numpy as np

    from damper_emulator.diagnose.base import make_record
    from damper_emulator.diagnose.discovery import LAGS_S, V_SIGN_M_S, Feature, motion

    m = motion(model, make_record(data, False), float(np.max(np.abs(data.displacement))),
               WARM_TEMPERATURE_C)
    m.terms_at(2.0 * V_SIGN_M_S)
    Feature("zone", "N·s/m", "position", 0, profile=(0.0, WARM_ZONE_WIDTH_M)).fn(m)
    Feature("lag", "-", "lag", 0, lag_s=LAGS_S[0]).fn(m)


def warm_nodes() -> None:
    """The kernels the nodes and ``replay`` run, and the damper's batch simulation
    (module docstring)."""
    import numpy as np

    from damper_emulator.bag.raw_topics import warm_up as warm_bag
    from damper_emulator.model.compressible import DamperModel, simulate
    from damper_emulator.realtime.core import EmulatorCore
    from damper_emulator.realtime.settings import EmulatorParams
    from damper_emulator.replay_emulation import run_model
    from ride_sim.params import load_quarter_car
    from ride_sim.session import RideSession

    model = DamperModel()
    EmulatorCore(model, EmulatorParams()).warm_up()
    car = load_quarter_car()
    RideSession.on_road(car, np.zeros(64), 0, 1e-3, 0.0).warm_up()
    warm_bag()
    stamps = np.array([0, 1_000_000], dtype=np.int64)
    run_model(model, stamps, np.zeros(2), np.zeros(2))
    run_model(model, stamps, np.zeros(2), np.zeros(2), np.ones(2))
    t = np.arange(64) * 1e-3
    simulate(model, t, 0.01 * np.sin(2.0 * np.pi * t))


def main() -> int:
    if sys.argv[1:] == [BATCH]:
        warm_batch()
        return 0
    seconds = warm_from_empty()
    print(f"damper-hil: kernels compiled and cached in {seconds:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
