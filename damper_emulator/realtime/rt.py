"""Operating-system real-time settings for a loop thread: ``SCHED_FIFO``, ``mlockall``, CPU
affinity, timer slack and a CPU wake-up latency request, each applied when permitted and
reported when not.

Linux applies scheduling policy, affinity and timer slack per thread: call
:func:`apply_realtime` from the loop thread itself.  ``mlockall`` is per process.  The wake-up
latency request (PM QoS, ``/dev/cpu_dma_latency``, as ``cyclictest`` makes it) is
system-wide and lasts while its file stays open: :meth:`RealtimeReport.release` closes it.
A thread that goes on after its loop (a run of several loops in one process) calls
:meth:`RealtimeReport.restore` to get its scheduling and affinity back: a thread it starts
later would otherwise inherit ``SCHED_FIFO``.
On a virtual machine whose idle CPUs halt, it is what brings the wake-up latency of a sleeping
loop from about 60 µs (p99 several hundred µs) down to about 30 µs (p99 about 50 µs); the
price is idle CPUs that poll instead of halting.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

#: ``mlockall`` flags (``<sys/mman.h>``): lock current and future pages; ``MCL_ONFAULT``
#: (Linux 4.4): lock each page when it is faulted in, not by faulting in every mapped page
#: now.  The pages a loop uses are resident by then (each node exercises its paths before
#: it is active), so they are locked at once; the rest of the mapped libraries (LLVM's,
#: scipy's: never run by the loop) stays on disk.  On the emulator's process this took
#: ``mlockall`` from 129 ms to 8 ms and its resident set from 521 to 228 MB, measured here.
_MCL_CURRENT, _MCL_FUTURE, _MCL_ONFAULT = 1, 2, 4
#: Python's GIL switch interval in a process whose real-time loop runs [s]: a thread that
#: wants the lock asks the holder for it after this long (the default, 5 ms, is five of a
#: loop's cycles).
GIL_SWITCH_INTERVAL_S = 1e-4
#: ``prctl`` option to set the calling thread's timer slack [ns] (``<linux/prctl.h>``).
_PR_SET_TIMERSLACK = 29
#: ``prctl`` option to name the calling thread (``comm``, 15 bytes; ``top -H`` shows it).
_PR_SET_NAME = 15
#: PM QoS device: an int32 written to it caps the CPUs' idle-state exit latency [µs] while
#: the file stays open (``Documentation/power/pm_qos_interface.rst``).
CPU_DMA_LATENCY_DEVICE = "/dev/cpu_dma_latency"


@dataclass(frozen=True)
class RealtimeRequest:
    """What the loop thread asks for."""

    sched_fifo: bool = True          # SCHED_FIFO at ``priority``
    priority: int = 80               # 1 (lowest) .. 99
    lock_memory: bool = True         # mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)
    cpu: int = -1                    # pin to this CPU; -1: leave the affinity alone
    timer_slack_ns: int = 1          # the thread's timer slack (Linux default 50 µs)
    cpu_dma_latency_us: int = -1     # cap on CPU wake-up latency [µs]; -1: no request


@dataclass
class RealtimeReport:
    """What was applied, and why the rest was not (one line each)."""

    applied: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    held_fds: list[int] = field(default_factory=list, repr=False)   # released by release()
    #: the thread's policy, parameters and affinity before the request (restored by restore())
    prior: tuple[int, os.sched_param, set[int]] | None = field(default=None, repr=False)

    def release(self) -> None:
        """Withdraw the requests that last while a file is open (the latency request)."""
        while self.held_fds:
            with contextlib.suppress(OSError):
                os.close(self.held_fds.pop())

    def restore(self) -> None:
        """:meth:`release`, and give the calling thread (the one that applied the request)
        its scheduling policy and CPU affinity back; ``mlockall`` stays (it is the
        process's).  Calling it again does nothing."""
        self.release()
        prior, self.prior = self.prior, None
        if prior is None:
            return
        policy, param, cpus = prior
        with contextlib.suppress(OSError, AttributeError):
            os.sched_setscheduler(0, policy, param)
        with contextlib.suppress(OSError, AttributeError, ValueError):
            os.sched_setaffinity(0, cpus)

    @property
    def sched_fifo(self) -> bool:
        return any(a.startswith("SCHED_FIFO") for a in self.applied)

    @property
    def memory_locked(self) -> bool:
        """``mlockall`` took (on fault, or at once)."""
        return any(a.startswith("mlockall") for a in self.applied)

    @property
    def pinned(self) -> bool:
        """The thread was pinned to a CPU (``RealtimeRequest.cpu``)."""
        return any(a.startswith("CPU ") for a in self.applied)

    def summary(self) -> str:
        parts = []
        if self.applied:
            parts.append("applied: " + ", ".join(self.applied))
        if self.refused:
            parts.append("not applied: " + "; ".join(self.refused))
        return "; ".join(parts) or "no real-time settings requested"


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name, use_errno=True) if name else None


def set_thread_name(name: str) -> None:
    """Name the calling OS thread (first 15 bytes), so that ``top -H``, ``ps -L`` and
    ``perf sched`` show the loop; nothing happens where ``prctl`` is missing."""
    libc = _libc()
    if libc is not None and hasattr(libc, "prctl"):
        libc.prctl(_PR_SET_NAME, ctypes.c_char_p(name.encode()[:15]), 0, 0, 0)


def unlock_memory() -> bool:
    """Undo ``mlockall`` for the process (``munlockall``): a managed node's ``cleanup``
    gives the memory back.  True when done."""
    libc = _libc()
    return libc is not None and int(libc.munlockall()) == 0


def apply_realtime(request: RealtimeRequest) -> RealtimeReport:
    """Apply ``request`` to the calling thread (and ``mlockall`` to the process).

    Never raises for a refusal (no privilege, no such CPU, not Linux): each is recorded in
    :attr:`RealtimeReport.refused` so that the caller can warn once and carry on.
    """
    report = RealtimeReport()
    with contextlib.suppress(OSError, AttributeError):
        report.prior = (os.sched_getscheduler(0), os.sched_getparam(0),
                        os.sched_getaffinity(0))
    libc = _libc()
    if request.lock_memory:
        if libc is None:
            report.refused.append("mlockall: no C library found")
        elif libc.mlockall(_MCL_CURRENT | _MCL_FUTURE | _MCL_ONFAULT) == 0:
            report.applied.append("mlockall (on fault)")
        elif libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:   # a kernel before 4.4
            report.applied.append("mlockall")
        else:
            err = ctypes.get_errno()
            report.refused.append(f"mlockall: {os.strerror(err)}")
    if request.cpu >= 0:
        try:
            os.sched_setaffinity(0, {request.cpu})
            report.applied.append(f"CPU {request.cpu}")
        except (OSError, AttributeError, ValueError) as exc:
            report.refused.append(f"affinity to CPU {request.cpu}: "
                                  f"{getattr(exc, 'strerror', None) or exc}")
    if request.sched_fifo:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(request.priority))
            report.applied.append(f"SCHED_FIFO priority {request.priority}")
        except (OSError, AttributeError) as exc:
            report.refused.append(f"SCHED_FIFO: {getattr(exc, 'strerror', None) or exc}")
    if request.cpu_dma_latency_us >= 0:
        _request_latency(request.cpu_dma_latency_us, report)
    if request.timer_slack_ns > 0 and libc is not None and libc.prctl(
            _PR_SET_TIMERSLACK, ctypes.c_ulong(request.timer_slack_ns), 0, 0, 0) == 0:
        report.applied.append(f"timer slack {request.timer_slack_ns} ns")
    return report


def _request_latency(latency_us: int, report: RealtimeReport) -> None:
    try:
        fd = os.open(CPU_DMA_LATENCY_DEVICE, os.O_WRONLY)
    except OSError as exc:
        report.refused.append(f"CPU wake-up latency {latency_us} µs: {exc.strerror}")
        return
    try:
        os.write(fd, struct.pack("i", int(latency_us)))
    except OSError as exc:
        os.close(fd)
        report.refused.append(f"CPU wake-up latency {latency_us} µs: {exc.strerror}")
        return
    report.held_fds.append(fd)
    report.applied.append(f"CPU wake-up latency ≤ {latency_us} µs")


def thread_ids() -> set[int]:
    """The OS thread ids of this process (Linux ``/proc/self/task``; empty elsewhere)."""
    try:
        return {int(t) for t in os.listdir("/proc/self/task")}
    except OSError:
        return set()


def set_threads_priority(tids: Iterable[int], priority: int) -> str:
    """Put the threads ``tids`` under ``SCHED_FIFO`` at ``priority`` (0: back to the normal
    policy); returns one line saying what was done or refused (never raises)."""
    tids = sorted(tids)
    if not tids:
        return "no threads"
    policy, param = ((os.SCHED_FIFO, os.sched_param(priority)) if priority > 0
                     else (os.SCHED_OTHER, os.sched_param(0)))
    done, refused = 0, ""
    for tid in tids:
        try:
            os.sched_setscheduler(tid, policy, param)
            done += 1
        except (OSError, AttributeError) as exc:   # gone, or not permitted
            refused = getattr(exc, "strerror", None) or str(exc)
    what = f"SCHED_FIFO priority {priority}" if priority > 0 else "normal scheduling"
    return f"{done} of {len(tids)} threads at {what}" + (f" ({refused})" if refused else "")


@contextlib.contextmanager
def normal_scheduling() -> Iterator[None]:
    """Run a block of the calling thread's work under the normal policy, and give the
    thread its policy and priority back afterwards (also when the block raises).

    For a real-time thread's long start-up work: a node's executor thread runs under
    ``SCHED_FIFO`` (:func:`~damper_emulator.ros.common.executor_priority`), and its
    ``configure`` builds the model and exercises its compiled code, seconds of CPU with an
    empty kernel cache.  Under ``SCHED_FIFO`` that work takes a CPU from every thread of a
    lower real-time priority (another process's control loop) until the kernel's real-time
    throttling stops all of them together (50 ms of every second by default).  A thread
    under the normal policy, or one whose policy cannot be read or set, runs the block
    as it is."""
    try:
        policy = os.sched_getscheduler(0)
        param = os.sched_getparam(0)
        real_time = policy in (os.SCHED_FIFO, os.SCHED_RR)
        if real_time:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        real_time = False
    try:
        yield
    finally:
        if real_time:
            os.sched_setscheduler(0, policy, param)


class ThreadInheritance:
    """Make the threads a block of code creates (the DDS middleware's, when it is the
    middleware's first use in the process) start under ``SCHED_FIFO``: the calling thread
    runs the block at a low real-time priority, which new threads inherit, and returns to
    the normal policy afterwards.  :meth:`settle` then sets those threads to the priority
    wanted (or back to normal)."""

    def __init__(self) -> None:
        self._before = thread_ids()
        self._entered = False

    def __enter__(self) -> ThreadInheritance:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            self._entered = True
        except (OSError, AttributeError):
            pass
        return self

    def __exit__(self, *exc: object) -> None:
        if self._entered:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))

    def settle(self, priority: int) -> str:
        """Set the threads created inside the block to ``priority`` (0: normal); one line."""
        new = thread_ids() - self._before
        if priority > 0 and not self._entered:
            return "middleware threads: SCHED_FIFO not permitted"
        return "middleware threads: " + set_threads_priority(new, priority)
