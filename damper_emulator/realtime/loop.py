"""A fixed-rate loop on its own thread, paced by absolute deadlines.

Deadlines are ``t0 + k·period`` on ``CLOCK_MONOTONIC`` (``time.sleep`` sleeps with
``clock_nanosleep`` on Linux), so the rate does not drift with the work done per tick.  A
tick that ends after its successor's deadline runs the successor at once; when the loop has
fallen more than one period behind it skips the missed deadlines (counted) instead of
running a burst of catch-up ticks.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from damper_emulator.realtime.rt import RealtimeReport, RealtimeRequest, apply_realtime


@dataclass(frozen=True)
class LoopSummary:
    """Period statistics of the latest ticks (at most the ring's capacity)."""

    ticks: int                 # ticks run since start
    achieved_rate_hz: float    # over the ticks in the ring
    period_p50_us: float
    period_p99_us: float
    period_max_us: float
    error_p99_us: float        # 99th percentile of |period − nominal|
    overruns: int              # periods longer than twice the nominal one, since start
    skipped: int               # deadlines skipped after falling behind, since start


def summarise(periods_ns: np.ndarray, period_ns: int, ticks: int, overruns: int,
              skipped: int) -> LoopSummary:
    """:class:`LoopSummary` of recorded periods [ns] around the nominal ``period_ns``."""
    p = np.asarray(periods_ns)
    if p.size == 0:
        nan = float("nan")
        return LoopSummary(ticks, nan, nan, nan, nan, nan, overruns, skipped)
    us = p / 1e3
    err = np.abs(p - period_ns) / 1e3
    return LoopSummary(ticks, float(1e9 / p.mean()), float(np.percentile(us, 50)),
                       float(np.percentile(us, 99)), float(us.max()),
                       float(np.percentile(err, 99)), overruns, skipped)


class LoopStats:
    """Ring buffer of tick periods [ns] and counters, written by the loop thread only.

    Readers take :meth:`summary` or :meth:`periods_ns` at any time; a reading may mix two
    consecutive ticks, which does not matter for statistics.
    """

    def __init__(self, period_ns: int, capacity: int = 1 << 17):
        self.period_ns = int(period_ns)
        self._ring = np.zeros(int(capacity), dtype=np.int64)
        self.ticks = 0          # ticks run
        self.recorded = 0       # periods recorded (ticks − 1)
        self.overruns = 0
        self.skipped = 0

    def record(self, period_ns: int) -> None:
        self._ring[self.recorded % self._ring.size] = period_ns
        self.recorded += 1
        if period_ns > 2 * self.period_ns:
            self.overruns += 1

    def periods_ns(self, last: int | None = None) -> np.ndarray:
        """The recorded periods in tick order: the latest ``last`` of them (default: all the
        ring holds)."""
        n = min(self.recorded, self._ring.size)
        if last is not None:
            n = min(n, int(last))
        end = self.recorded % self._ring.size
        idx = np.arange(end - n, end) % self._ring.size
        return self._ring[idx]

    def summary(self, last: int | None = None) -> LoopSummary:
        """Statistics of the latest ``last`` periods (default: all the ring holds); the
        counters are since start.  Keep ``last`` small on a thread that shares the GIL with
        the loop: the percentiles of a long record take milliseconds."""
        return summarise(self.periods_ns(last), self.period_ns, self.ticks, self.overruns,
                         self.skipped)


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

    @property
    def running(self) -> bool:
        return self._thread.is_alive() and not self._stop.is_set()

    def _run(self) -> None:
        if self._request is not None:
            self.report = apply_realtime(self._request)
        self._started.set()
        period = self.period_ns
        stats = self.stats
        clock = time.monotonic_ns
        sleep = time.sleep
        deadline = clock() + period
        previous = 0
        try:
            while not self._stop.is_set():
                delay = deadline - clock()
                if delay > 0:
                    sleep(delay * 1e-9)
                now = clock()
                if previous:
                    stats.record(now - previous)
                previous = now
                stats.ticks += 1
                self._tick(now)
                deadline += period
                behind = clock() - deadline
                if behind > period:
                    missed = behind // period
                    deadline += missed * period
                    stats.skipped += int(missed)
        except BaseException as exc:  # noqa: BLE001 - reported to the owner
            self.error = exc
            self._stop.set()
