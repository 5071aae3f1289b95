"""Ctrl-C and a kill held back over a few statements that must not be cut in two.

:func:`signals_held` runs SIGINT's and SIGTERM's Python handlers only once its block is
done: the outputs renamed into place as one set
(:meth:`damper_emulator.outputs.Outputs.commit`), a node's process started and kept where
the caller's stop finds it (:mod:`damper_emulator.ros.launch`).  This module imports
nothing from the project.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["HELD_SIGNALS", "signals_held"]

#: the signals whose handlers :func:`signals_held` holds: Ctrl-C and a kill
HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT's and SIGTERM's Python handlers while the block runs, then run them
    for each that arrived (their handlers raise, as the command line's do, and would
    otherwise cut the block anywhere).  Signals with no Python handler, and blocks run in
    another thread than the main one (where Python runs no handler), are left alone."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = {s: h for s in HELD_SIGNALS if (h := signal.getsignal(s)) is not None}
    for s in held:
        signal.signal(s, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        for s, handler in held.items():
            signal.signal(s, handler)
        for signum in caught:
            signal.raise_signal(signum)
