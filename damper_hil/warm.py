"""Load or compile the kernels a first run needs, once, at install.

``make``'s install step runs ``python -m damper_hil.warm``: numba's on-disk cache
(:mod:`damper_emulator.model.jit`: ``$NUMBA_CACHE_DIR``, else the user's cache directory,
one directory per version of the sources) then holds the compiled kernels, and the first
``damper-hil`` command or node loads them instead of compiling for seconds.  What is
warmed is what the nodes warm before they say they are ready: the emulator's core (the
damper's step, every input and fault mode), the ride's session (the quarter car), the bag
reader's helpers, and the batch loops over recorded samples that ``replay`` runs, with
and without a valve command (about 1 s of a first replay's compiling otherwise).  Prints
one line with the time it took.
"""

from __future__ import annotations

import sys
import time


def warm() -> float:
    """Exercise the kernels (module docstring); returns the seconds it took."""
    start = time.monotonic()
    import numpy as np

    from damper_emulator.bag.raw_topics import warm_up as warm_bag
    from damper_emulator.model.compressible import DamperModel
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
    return time.monotonic() - start


def main() -> int:
    seconds = warm()
    print(f"damper-hil: kernels compiled and cached in {seconds:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
