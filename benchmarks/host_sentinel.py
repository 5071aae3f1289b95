#!/usr/bin/env python3
"""A host-stall sentinel: one SCHED_FIFO thread pinned to one CPU that wakes every
millisecond on absolute ``CLOCK_MONOTONIC`` deadlines and records every wake-up later than
a threshold, as ``(deadline_ns, wake_ns)`` on the monotonic clock the emulator's loop record
uses.  Run one per CPU beside a real-time loop (:mod:`demo_bench`): a loop overrun that
coincides with a late wake-up of an independent thread on the same machine is a stall of the
machine (a hypervisor stopping the vCPU), not of the loop.

Usage: ``python host_sentinel.py CPU SECONDS OUT.npy [--priority P] [--late-us US]``
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time

import numpy as np

#: Wake-ups later than this are recorded [µs]: well above a busy CPU's scheduling delay of a
#: thread at the loop's priority (a tick's work, at most some hundred µs).
LATE_US = 1000
PERIOD_NS = 1_000_000


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cpu", type=int)
    ap.add_argument("seconds", type=float)
    ap.add_argument("out")
    ap.add_argument("--priority", type=int, default=80)
    ap.add_argument("--late-us", type=float, default=LATE_US)
    args = ap.parse_args()
    try:
        os.sched_setaffinity(0, {args.cpu})
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
    except OSError as exc:
        print(f"host_sentinel: real-time settings refused ({exc.strerror}): no sentinel",
              file=sys.stderr)
        return 2
    late_ns = int(args.late_us * 1000)
    events = []
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))   # stop early: still save
    clock = time.monotonic_ns
    deadline = clock() + PERIOD_NS
    end = deadline + int(args.seconds * 1e9)
    try:
        while deadline < end:
            delay = deadline - clock()
            if delay > 0:
                time.sleep(delay * 1e-9)
            now = clock()
            if now - deadline > late_ns:
                events.append((deadline, now))
            deadline += PERIOD_NS
            if now > deadline:          # skip what was missed, as the loops do
                deadline += (now - deadline) // PERIOD_NS * PERIOD_NS + PERIOD_NS
    finally:
        np.save(args.out, np.array(events, dtype=np.int64).reshape(-1, 2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
