"""A fixed-rate loop on its own thread, paced by absolute deadlines.

Deadlines are ``t0 + k·period`` on ``CLOCK_MONOTONIC`` (``time.sleep`` sleeps with
``clock_nanosleep`` on Linux), so the rate does not drift with the work done per tick.  A
tick that ends after its successor's deadline runs the successor at once; when the loop has
fallen more than one period behind it skips the missed deadlines (counted) instead of
running a burst of catch-up ticks.  A tick may move the next deadline (and so all later
ones) by :meth:`PeriodicLoop.shift_next` (a phase lock to the input,
:mod:`damper_emulator.realtime.phase_lock`).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from damper_emulator.realtime.rt import (
    RealtimeReport,
    RealtimeRequest,
    apply_realtime,
    set_thread_name,
)


@dataclass(frozen=True)
class LoopSummary:
    """Statistics of the latest ticks (at most the ring's capacity)."""

    ticks: int                 # ticks run since start
    achieved_rate_hz: float    # over the ticks in the ring
    period_p50_us: float
    period_p99_us: float
    period_max_us: float
    error_p99_us: float        # 99th percentile of |period − nominal|
    overruns: int              # periods longer than twice the nominal one, since start
    skipped: int               # deadlines skipped after falling behind, since start
                               # (counted as the tick after them runs)
    wake_p50_us: float = float("nan")   # wake-up after the deadline (latency)
    wake_p99_us: float = float("nan")
    work_p99_us: float = float("nan")   # time spent in tick()
    work_max_us: float = float("nan")


def _p(x_us: np.ndarray, q: float) -> float:
    return float(np.percentile(x_us, q)) if x_us.size else float("nan")


def summarise(periods_ns: np.ndarray, period_ns: int, ticks: int, overruns: int,
              skipped: int, wake_ns: np.ndarray | None = None,
              work_ns: np.ndarray | None = None) -> LoopSummary:
    """:class:`LoopSummary` of recorded periods [ns] around the nominal ``period_ns``, and of
    the wake-up latencies and tick durations [ns] when given."""
    p = np.asarray(periods_ns)
    wake = np.asarray(wake_ns if wake_ns is not None else [], dtype=float) / 1e3
    work = np.asarray(work_ns if work_ns is not None else [], dtype=float) / 1e3
    timing = dict(wake_p50_us=_p(wake, 50), wake_p99_us=_p(wake, 99), work_p99_us=_p(work, 99),
                  work_max_us=float(work.max()) if work.size else float("nan"))
    if p.size == 0:
        nan = float("nan")
        return LoopSummary(ticks, nan, nan, nan, nan, nan, overruns, skipped, **timing)
    us = p / 1e3
    err = np.abs(p - period_ns) / 1e3
    return LoopSummary(ticks, float(1e9 / p.mean()), _p(us, 50), _p(us, 99), float(us.max()),
                       _p(err, 99), overruns, skipped, **timing)


class LoopStats:
    """Ring buffers of tick periods, wake-up latencies and tick durations [ns], and counters,
    written by the loop thread only.

    Readers take :meth:`summary` or :meth:`periods_ns` at any time; a reading may mix two
    consecutive ticks, which does not matter for statistics.
    """

    def __init__(self, period_ns: int, capacity: int = 1 << 17):
        self.period_ns = int(period_ns)
        self._ring = np.zeros(int(capacity), dtype=np.int64)
        self._wake = np.zeros(int(capacity), dtype=np.int64)
        self._work = np.zeros(int(capacity), dtype=np.int64)
        self.ticks = 0          # ticks run (= wake-ups and durations recorded)
        self.recorded = 0       # periods recorded (ticks − 1)
        self.overruns = 0
        self.skipped = 0
        #: ``time.monotonic_ns()`` of the first tick (0: none yet); with the periods it
        #: places every tick on the machine's monotonic clock
        self.first_tick_ns = 0

    def record(self, period_ns: int) -> None:
        self._ring[self.recorded % self._ring.size] = period_ns
        self.recorded += 1
        if period_ns > 2 * self.period_ns:
            self.overruns += 1

    def record_tick(self, wake_ns: int, work_ns: int) -> None:
        """One tick's wake-up after its deadline and time spent in it [ns]."""
        i = self.ticks % self._wake.size
        self._wake[i] = wake_ns
        self._work[i] = work_ns
        self.ticks += 1

    @staticmethod
    def _latest(ring: np.ndarray, count: int, last: int | None) -> np.ndarray:
        n = min(count, ring.size)
        if last is not None:
            n = min(n, int(last))
        end = count % ring.size
        return ring[np.arange(end - n, end) % ring.size]

    def periods_ns(self, last: int | None = None) -> np.ndarray:
        """The recorded periods in tick order: the latest ``last`` of them (default: all the
        ring holds)."""
        return self._latest(self._ring, self.recorded, last)

    def wake_ns(self, last: int | None = None) -> np.ndarray:
        """Wake-up latencies (wake-up − deadline) in tick order, like :meth:`periods_ns`."""
        return self._latest(self._wake, self.ticks, last)

    def work_ns(self, last: int | None = None) -> np.ndarray:
        """Time spent in each tick, like :meth:`periods_ns`."""
        return self._latest(self._work, self.ticks, last)

    def summary(self, last: int | None = None) -> LoopSummary:
        """Statistics of the latest ``last`` ticks (default: all the ring holds); the
        counters are since start.  Keep ``last`` small on a thread that shares the GIL with
        the loop: the percentiles of a long record take milliseconds."""
        return summarise(self.periods_ns(last), self.period_ns, self.ticks, self.overruns,
                         self.skipped, self.wake_ns(last), self.work_ns(last))

    def save(self, path: str | os.PathLike[str], **extra: Any) -> None:
        """Write the record (:func:`load_record` reads it) as ``.npz``, with ``extra``."""
        np.savez(path, periods_ns=self.periods_ns(), wake_ns=self.wake_ns(),
                 work_ns=self.work_ns(), period_ns=self.period_ns, ticks=self.ticks,
                 overruns=self.overruns, skipped=self.skipped,
                 first_tick_ns=self.first_tick_ns, **extra)


def load_record(path: str | os.PathLike[str]) -> tuple[dict[str, np.ndarray], LoopSummary]:
    """``(arrays, summary)`` of a record written by :meth:`LoopStats.save` (records written
    before wake-up and work times were kept read too)."""
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    s = summarise(data["periods_ns"], int(data["period_ns"]), int(data["ticks"]),
                  int(data["overruns"]), int(data["skipped"]), data.get("wake_ns"),
                  data.get("work_ns"))
    return data, s


class PeriodicLoop:
    """Run ``tick(now_ns)`` every ``period_s`` on a dedicated thread.

    Parameters
    ----------
    period_s : float
        Nominal period [s].
    tick : callable
        ``tick(now_ns)`` with ``now_ns`` the ``time.monotonic_ns()`` at wake-up.  An
        exception stops the loop; it is kept in :attr:`error`.
    realtime : RealtimeRequest, optional
        Applied from the loop thread before the first tick; the outcome is in
        :attr:`report` once :meth:`start` returns.
    capacity : int
        Periods kept for the statistics (:class:`LoopStats`).
    """

    def __init__(self, period_s: float, tick: Callable[[int], None], *,
                 realtime: RealtimeRequest | None = None, capacity: int = 1 << 17,
                 name: str = "rt-loop"):
        self.period_ns = max(1, int(round(period_s * 1e9)))
        self._tick = tick
        self._request = realtime
        self.stats = LoopStats(self.period_ns, capacity)
        self.report = RealtimeReport()
        self.error: BaseException | None = None
        self._shift_ns = 0
        self._stop = threading.Event()
        self._started = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        self._thread.start()
        self._started.wait()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)

    def shift_next(self, shift_ns: int) -> None:
        """Move the next deadline, and every later one, by ``shift_ns`` (+: later).  Called
        from ``tick`` (the loop's thread); the shifts of one tick add up."""
        self._shift_ns += int(shift_ns)

    @property
    def running(self) -> bool:
        return self._thread.is_alive() and not self._stop.is_set()

    def _run(self) -> None:
        set_thread_name(self._thread.name)
        if self._request is not None:
            self.report = apply_realtime(self._request)
        self._started.set()
        period = self.period_ns
        stats = self.stats
        clock = time.monotonic_ns
        sleep = time.sleep
        deadline = clock() + period
        previous = 0
        # deadlines skipped since the last tick: counted when the next tick runs (a loop
        # stopped in between skipped none its ticks show)
        missed = 0
        try:
            while not self._stop.is_set():
                delay = deadline - clock()
                if delay > 0:
                    sleep(delay * 1e-9)
                now = clock()
                if previous:
                    stats.record(now - previous)
                else:
                    stats.first_tick_ns = now
                previous = now
                stats.skipped += missed
                missed = 0
                self._tick(now)
                stats.record_tick(now - deadline, clock() - now)
                deadline += period + self._shift_ns
                self._shift_ns = 0
                behind = clock() - deadline
                if behind > period:
                    missed = int(behind // period)
                    deadline += missed * period
        except BaseException as exc:  # noqa: BLE001 - reported to the owner
            self.error = exc
            self._stop.set()
        finally:
            self.report.release()
