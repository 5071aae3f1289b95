"""Witnesses of the machine's stalls for the tests whose guarantees hold only while the
machine lets the code run (a virtual machine halts its vCPUs for up to seconds): one
SCHED_FIFO sentinel thread per CPU (``benchmarks/host_sentinel.py``) logs its late
wake-ups beside the run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

#: One SCHED_FIFO thread per CPU that logs its late wake-ups.
SENTINEL = Path(__file__).resolve().parents[1] / "benchmarks" / "host_sentinel.py"
#: Late wake-ups shorter than this are the host's jitter, not a stall [ms].
LATE_MS = 10.0
#: A run that the machine stalled is run again, at most this many times in all.
RUNS_THROUGH_STALLS = 3


class Sentinels:
    """:data:`SENTINEL` on every CPU while a run lasts; :attr:`stalls` then holds each late
    wake-up as (its deadline, its lateness [ms]) on the monotonic clock (none where the
    machine refuses SCHED_FIFO)."""

    def __init__(self, folder: Path) -> None:
        cpus = sorted(os.sched_getaffinity(0))
        self.files = [folder / f"sentinel{cpu}.npy" for cpu in cpus]
        self.procs = [subprocess.Popen([sys.executable, str(SENTINEL), str(cpu), "3600",
                                        str(f), "--late-us", str(LATE_MS * 1000)],
                                       stderr=subprocess.DEVNULL)
                      for cpu, f in zip(cpus, self.files, strict=True)]
        self.stalls: list[tuple[float, float]] = []

    def close(self) -> None:
        for proc in self.procs:
            proc.terminate()
        for proc in self.procs:
            proc.wait(20)
        for f in self.files:
            if f.exists():
                self.stalls += [(d * 1e-9, (w - d) * 1e-6) for d, w in np.load(f)]

    def __enter__(self) -> Sentinels:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def stalled_ms(self, start_s: float, end_s: float) -> float:
        """The sum of the stalls' parts inside ``[start_s, end_s]`` (monotonic) [ms]."""
        return sum(max(0.0, min(end_s, s + ms * 1e-3) - max(start_s, s)) * 1e3
                   for s, ms in self.stalls)
