"""A process for the work a real-time loop hands off (a fit), away from the loop's GIL.

A thread of the loop's own process that runs Python shares the interpreter's lock (the
GIL) with the loop: while it computes, the loop waits for the lock at every wake, a switch
interval at least (:data:`~damper_emulator.realtime.rt.GIL_SWITCH_INTERVAL_S`), and for as
long again as that thread, under the normal policy beside every other process of the
machine, is kept off its CPU while it holds the lock.  The loop's real-time policy does
not help there: it waits for a lock, not for a CPU.  ``benchmarks/offloop_bench.py``
measures the loop's lateness both ways.

:class:`OffLoopWorker` runs the work in a process of its own, spawned under the normal
policy, and hands each result back through a pipe that the loop polls (:meth:`Job.done`):
between two polls nothing of the worker runs in the loop's process.
``concurrent.futures.ProcessPoolExecutor`` would run the work as well, but it adds a
thread of its own to the loop's process (Python, under the normal policy: the same lock
again), and before Python 3.14 it cannot end a task that is running (a run stopped while
it fits would wait for the fit).
"""

from __future__ import annotations

import contextlib
import importlib
import multiprocessing
import os
import signal
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any, Generic, Protocol, TypeVar

from damper_emulator.errors import DamperHilError
from damper_emulator.realtime.rt import normal_scheduling

T = TypeVar("T")
T_co = TypeVar("T_co", covariant=True)

#: How long :meth:`OffLoopWorker.close` waits for an idle worker to end by itself before
#: it ends it [s].
CLOSE_TIMEOUT_S = 2.0
#: How long a waiting read that found the worker's pipe closed waits for the worker's exit
#: status (the pipe closes as the process dies, a moment before the kernel reports its
#: status); a poll (:meth:`Job.done`, a loop's) does not wait [s].
EXIT_STATUS_WAIT_S = 0.5


class Pending(Protocol[T_co]):
    """What a loop polls for work it handed off: a :class:`Job`, or a
    :class:`concurrent.futures.Future`."""

    def done(self) -> bool: ...

    def result(self) -> T_co: ...


class Executor(Protocol):
    """What a loop hands work to: an :class:`OffLoopWorker`, or anything with ``submit``
    (one that runs it at once, for offline runs and tests)."""

    def submit(self, fn: Callable[..., T], *args: Any) -> Pending[T]: ...


class WorkerError(DamperHilError):
    """The worker process ended, or a task's result could not be handed back."""


def _worker_main(conn: Connection, preload: tuple[str, ...]) -> None:
    """The worker: imports ``preload``, then runs each ``(job, fn, args)`` it receives and
    sends back ``(job, True, result)`` or ``(job, False, exception)``, until ``None`` or
    the end of the pipe."""
    # a Ctrl-C in a terminal reaches the whole process group: the parent decides
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(OSError, AttributeError):   # inherited from a real-time thread
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    for name in preload:
        importlib.import_module(name)
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):       # the parent has gone
            return
        if message is None:
            return
        job, fn, args = message
        try:
            answer: tuple[int, bool, Any] = (job, True, fn(*args))
        except Exception as exc:  # noqa: BLE001 - handed back to the caller
            answer = (job, False, exc)
        try:
            conn.send(answer)
        except (EOFError, OSError):
            return
        except Exception as exc:  # noqa: BLE001 - a result that cannot be pickled
            conn.send((job, False, WorkerError(f"{fn.__qualname__}'s result could not be "
                                               f"handed back: {exc}")))


class Job(Generic[T]):
    """One task given to an :class:`OffLoopWorker`: :meth:`done` polls (never waits),
    :meth:`result` waits."""

    def __init__(self, worker: OffLoopWorker, job: int) -> None:
        self._worker = worker
        self._job = job
        self._outcome: tuple[bool, Any] | None = None

    def done(self) -> bool:
        """Whether the result (or the task's exception) is here; reads what the pipe holds
        and returns at once."""
        if self._outcome is None:
            self._outcome = self._worker._collect(self._job, wait=False)
        return self._outcome is not None

    def result(self) -> T:
        """The task's result; waits for it.

        Raises
        ------
        Exception
            The task's own exception.
        WorkerError
            The worker process ended before it handed the result back.
        """
        if self._outcome is None:
            self._outcome = self._worker._collect(self._job, wait=True)
        assert self._outcome is not None
        ok, value = self._outcome
        if not ok:
            raise value
        return value  # type: ignore[no-any-return]


class OffLoopWorker:
    """One worker process; :meth:`submit` gives it a task, run in the order given.

    Parameters
    ----------
    name : str
        The process's name (``ps``, error messages).
    preload : tuple of str
        Modules the worker imports as it starts: the first task does not wait for them.

    The task's function and arguments travel by pickle (a function of a module, by its
    name).  The worker starts at once, under the normal policy whatever the calling
    thread's; it ignores ``SIGINT`` (its parent decides) and ends with the pipe when its
    parent does.  :meth:`close` ends it (idempotent).
    """

    def __init__(self, name: str, preload: tuple[str, ...] = ()) -> None:
        self.name = name
        ctx = multiprocessing.get_context("spawn")
        ours, theirs = ctx.Pipe(duplex=True)
        self._process: Any = ctx.Process(target=_worker_main, name=name,
                                         args=(theirs, tuple(preload)), daemon=True)
        with normal_scheduling():          # not the caller's SCHED_FIFO, if it has one
            self._process.start()
        theirs.close()
        self._conn: Connection | None = ours
        self._next = 0
        #: outcomes handed back and not yet taken by their job, by job
        self._outcomes: dict[int, tuple[bool, Any]] = {}
        self._running: set[int] = set()      # given, not handed back yet

    def submit(self, fn: Callable[..., T], *args: Any) -> Job[T]:
        """Give the worker ``fn(*args)``; its :class:`Job`.

        Raises
        ------
        WorkerError
            The worker has been closed or has ended.
        """
        if self._conn is None:
            raise WorkerError(f"{self.name}: the worker has been closed")
        job = self._next
        self._next += 1
        try:
            self._conn.send((job, fn, args))
        except (EOFError, OSError) as exc:
            raise WorkerError(f"{self.name}: the worker process has ended (status "
                              f"{self._process.exitcode}): {exc}") from exc
        self._running.add(job)
        return Job(self, job)

    def _collect(self, job: int, wait: bool) -> tuple[bool, Any] | None:
        """``job``'s outcome ``(ok, result or exception)``, taken from the worker; None when
        it is not there yet (and not ``wait``)."""
        while job in self._running:
            if not self._read(wait):
                return None
        return self._outcomes.pop(job, None)

    def _read(self, wait: bool) -> bool:
        """Read one outcome from the pipe; False when none is there (and not ``wait``).  A
        worker that has ended leaves every running job a :class:`WorkerError`."""
        conn = self._conn
        try:
            if conn is None:
                raise EOFError
            if not conn.poll(None if wait else 0):
                return False
            job, ok, value = conn.recv()
        except (EOFError, OSError):
            self._process.join(EXIT_STATUS_WAIT_S if wait else 0.0)
            status = self._process.exitcode
            ended = WorkerError(f"{self.name}: the worker process ended"
                                + (f" (status {status})" if status is not None else "")
                                + " before it handed a result back")
            self._outcomes.update((job, (False, ended)) for job in self._running)
            self._running.clear()
            return True
        self._running.discard(job)
        self._outcomes[job] = (ok, value)
        return True

    def close(self) -> None:
        """End the worker: a task still running is ended with it (a stopped run does not
        wait for its fit); an idle worker ends by itself (:data:`CLOSE_TIMEOUT_S`)."""
        if self._conn is not None:
            while self._running and self._read(wait=False):
                pass
            with contextlib.suppress(OSError):
                self._conn.send(None)
            self._conn.close()
            self._conn = None
        if not self._running:
            self._process.join(CLOSE_TIMEOUT_S)
        if self._process.is_alive():
            self._process.terminate()
        self._process.join()

    def __enter__(self) -> OffLoopWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
