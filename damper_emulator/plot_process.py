"""Draw a figure in a process of its own, started before the work it shows.

Importing matplotlib takes about half a second, as long as a replay's whole work: a
command that starts :class:`PlotProcess` first has it import matplotlib on another core
while it works, then hands it the figure's data (plain arrays, pickled over a pipe) and
waits for the file.  The child runs ``python -m damper_emulator.plot_process MODULE
FUNCTION [PRELOAD ...]``: it imports the ``PRELOAD`` modules and ``MODULE`` at once, reads
the call's arguments from its standard input, calls ``MODULE.FUNCTION(*args)`` and writes
back the result or the exception.
"""

from __future__ import annotations

import importlib
import pickle
import subprocess
import sys
from typing import Any

from damper_emulator.errors import DamperHilError

#: how long a figure may take to draw, once its data are sent [s]
DRAW_TIMEOUT_S = 120.0


class PlotProcessError(DamperHilError):
    """The drawing process ended without an answer (killed, or out of memory): a bug or
    the machine's, not the user's input."""


class PlotProcess:
    """A process that imports ``preload`` and ``module`` now and calls ``module.function``
    once, with the arguments :meth:`call` gives it.  Close it (or use it as a context
    manager) to end it when :meth:`call` was not reached."""

    def __init__(self, module: str, function: str, preload: tuple[str, ...] = ()):
        self._proc: subprocess.Popen[bytes] | None = subprocess.Popen(
            [sys.executable, "-m", __name__, module, function, *preload],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def call(self, *args: Any) -> Any:
        """``module.function(*args)`` in the process; its result, or its exception raised
        here."""
        proc = self._proc
        if proc is None:
            raise PlotProcessError("the drawing process was already used or closed")
        self._proc = None
        try:
            out, _ = proc.communicate(pickle.dumps(args), timeout=DRAW_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            raise PlotProcessError(f"the figure took longer than {DRAW_TIMEOUT_S:g} s to "
                                   "draw") from None
        try:
            ok, value = pickle.loads(out)
        except Exception:  # noqa: BLE001 - no answer at all: say how the process ended
            raise PlotProcessError(f"the drawing process ended without an answer (exit "
                                   f"{proc.returncode})") from None
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """End the process if :meth:`call` was not reached."""
        if self._proc is not None:
            self._proc.kill()
            self._proc.wait()
            for pipe in (self._proc.stdin, self._proc.stdout):
                if pipe is not None:
                    pipe.close()
            self._proc = None

    def __enter__(self) -> PlotProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve(module: str, function: str, preload: list[str]) -> int:
    """The child: import, wait for the arguments, call, answer."""
    for name in preload:
        importlib.import_module(name)
    target = getattr(importlib.import_module(module), function)
    data = sys.stdin.buffer.read()
    if not data:
        return 0                       # closed before a call: nothing to draw
    args = pickle.loads(data)
    try:
        answer: tuple[bool, Any] = (True, target(*args))
    except Exception as exc:  # noqa: BLE001 - raised again in the caller
        answer = (False, exc)
    try:
        payload = pickle.dumps(answer)
    except Exception as exc:  # noqa: BLE001 - an exception that does not pickle
        payload = pickle.dumps((False, PlotProcessError(repr(exc))))
    sys.stdout.buffer.write(payload)
    sys.stdout.buffer.flush()
    return 0


if __name__ == "__main__":
    sys.exit(_serve(sys.argv[1], sys.argv[2], sys.argv[3:]))
