"""Shared pieces of the property-based reader tests (``tests/test_fuzz_*.py``).

Each of those tests feeds a reader of untrusted input (a data file, a parameter file, a
bag, a CAN frame, a CAN database) whatever hypothesis makes of it and checks that the
result is a value or the project's user error.  This module holds what they share: a
time limit that turns a hang into a failure, and strategies for junk bytes and text.
The hypothesis settings come from the profile ``tests/conftest.py`` loads
(``HYPOTHESIS_PROFILE``: ``default`` for ``make test``, ``fuzz`` for ``make fuzz``).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

from hypothesis import strategies as st

#: Longest a reader may take on one example before the test calls it a hang [s].  The
#: examples are small (a few kilobytes), so a healthy reader answers in milliseconds; the
#: limit is generous for a loaded 2-core machine whose guest stalls for up to a third of a
#: second, and for a first call that compiles numba kernels.
TIME_LIMIT_S = 30.0


class Hang(BaseException):
    """A reader ran past :data:`TIME_LIMIT_S`.

    A ``BaseException`` (like ``KeyboardInterrupt``): a reader's ``except Exception``
    that turns any library failure into its user error must not swallow it.
    """


@contextlib.contextmanager
def time_limit(seconds: float = TIME_LIMIT_S) -> Iterator[None]:
    """Raise :class:`Hang` in the block when it runs longer than ``seconds``.

    By ``SIGALRM``, so in the main thread only (where pytest runs the tests); elsewhere
    the block runs without a limit.  Python code is interrupted between bytecodes: a loop
    in Python stops, a single call into C that never returns does not.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_alarm(signum: int, frame: object) -> None:
        raise Hang(f"no result within {seconds:g} s: the reader hangs on this input")

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


#: Any bytes, up to a few kilobytes: what a truncated download or a binary file holds.
junk_bytes = st.binary(max_size=4096)

#: Any text, control characters, NUL, BOM and surrogate-free astral characters included.
junk_text = st.text(st.characters(exclude_categories=("Cs",)), max_size=1000)


@st.composite
def mutated_bytes(draw: st.DrawFn, original: bytes, max_ops: int = 4) -> bytes:
    """``original`` with 1 to ``max_ops`` byte-level changes: truncated, bytes flipped,
    overwritten, inserted or deleted, at offsets spread over the whole of it."""
    data = bytearray(original)
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(st.sampled_from(("truncate", "flip", "overwrite", "insert", "delete")))
        at = draw(st.integers(0, len(data)))
        if op == "truncate":
            del data[at:]
        elif op == "flip" and at < len(data):
            data[at] ^= draw(st.integers(1, 255))
        elif op == "overwrite":
            chunk = draw(st.binary(min_size=1, max_size=16))
            data[at:at + len(chunk)] = chunk
        elif op == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=64))
        elif op == "delete":
            del data[at:at + draw(st.integers(1, 64))]
    return bytes(data)
