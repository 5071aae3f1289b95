#!/usr/bin/env python3
"""Benchmark: how late a 1 kHz real-time loop runs while the identification's fit runs
beside it, the fit in a thread of the loop's process or in an
:class:`~damper_emulator.realtime.worker.OffLoopWorker`; prints a markdown table.

The loop: a thread under ``SCHED_FIFO`` (priority 79, a rig host's), pinned to the last
CPU, that wakes every millisecond on absolute deadlines and does a little Python work, as
a host's cycle does, with the GIL's switch interval the hybrid link sets; its lateness is
each wake's delay after its deadline.  The work:
:func:`ride_sim.hybrid.rig_host._fit_and_tracker` on a noisy identification, one fit after
another for the whole window, in a thread of this process (under the normal policy, as
``hybrid`` ran it before) or in the worker process.  Each case runs idle and beside
``--busy`` processes that spin under the normal policy (a loaded machine: the test
suite's other worker, a compile).  The rig's watchdog is 50 ms; a cycle three periods late
is a stall the identification leaves out (:data:`~ride_sim.hybrid.rig_host.STALL_CYCLES`).

Usage: ``python benchmarks/offloop_bench.py [--seconds S] [--repeats N] [--busy N]``
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from damper_emulator.realtime.rt import GIL_SWITCH_INTERVAL_S
from damper_emulator.realtime.worker import OffLoopWorker
from ride_sim.hybrid.params import CompensatorParams, SafetyParams
from ride_sim.hybrid.rig_host import STALL_CYCLES, _fit_and_tracker, fit_worker
from ride_sim.hybrid.transfer import NOMINAL_ESTIMATE, excitation, response

PERIOD_S = 1e-3
PRIORITY = 79
#: the noise on the identification's measurement, of its r.m.s. [-]
NOISE = 0.02


def identification() -> tuple[Any, ...]:
    """The fit's arguments: the default identification signal through the nominal rig,
    with noise."""
    p = CompensatorParams()
    u = excitation(p.identify_s, PERIOD_S, p.identify_amplitude_m, p.identify_band_hz,
                   seed=1)
    x = response(u, PERIOD_S, NOMINAL_ESTIMATE)
    x = x + NOISE * np.std(x) * np.random.default_rng(2).standard_normal(x.size)
    return u, x, PERIOD_S, p, np.ones(u.size, dtype=bool)


def loop(seconds: float, lateness: list[float], cpu: int) -> None:
    """The real-time loop (see the module docstring); appends each wake's lateness [s]."""
    try:
        os.sched_setaffinity(0, {cpu})
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
    except OSError:
        pass                              # the normal policy: the table says which ran
    deadline = time.monotonic() + PERIOD_S
    end = deadline + seconds
    acc = 0.0
    while deadline < end:
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        now = time.monotonic()
        lateness.append(now - deadline)
        for k in range(50):               # a cycle's bit of Python
            acc += k * 1e-9
        deadline += PERIOD_S
        if now > deadline:
            deadline += (now - deadline) // PERIOD_S * PERIOD_S + PERIOD_S


def measure(where: str, busy: int, seconds: float) -> dict[str, Any]:
    """One case: the loop's lateness while fits run ``where`` ("thread" or "process")
    beside ``busy`` spinning processes."""
    args = identification()
    executor: Any
    if where == "thread":
        executor = ThreadPoolExecutor(max_workers=1)
        executor.submit(int).result()         # its thread starts under the normal policy
    else:
        executor = fit_worker("offloop-bench")
        executor.submit(int).result()         # imported and ready
    spinners = [subprocess.Popen(["sh", "-c", "while :; do :; done"]) for _ in range(busy)]
    lateness: list[float] = []
    fits = 0
    try:
        thread = threading.Thread(target=loop, args=(seconds, lateness, os.cpu_count() - 1))
        thread.start()
        while thread.is_alive():
            executor.submit(_fit_and_tracker, *args).result()
            fits += 1
        thread.join()
    finally:
        for p in spinners:
            p.kill()
            p.wait()
        if isinstance(executor, OffLoopWorker):
            executor.close()
        else:
            executor.shutdown()
    late_ms = np.asarray(lateness) * 1e3
    return {"where": where, "busy": busy, "fits": fits, "cycles": late_ms.size,
            "p50": float(np.percentile(late_ms, 50)), "p99": float(np.percentile(late_ms, 99)),
            "max": float(late_ms.max()),
            "stalls": int(np.count_nonzero(late_ms > STALL_CYCLES * PERIOD_S * 1e3)),
            "watchdog": int(np.count_nonzero(late_ms > SafetyParams().watchdog_s * 1e3))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="each case's window [s]")
    ap.add_argument("--repeats", type=int, default=2, help="runs of each case")
    ap.add_argument("--busy", type=int, default=4,
                    help="spinning processes of the loaded cases")
    a = ap.parse_args()
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    rows = []
    cases = [(where, busy) for busy in (0, a.busy) for where in ("thread", "process")]
    for i, (where, busy) in enumerate(cases * a.repeats):
        print(f"[{i + 1}/{len(cases) * a.repeats}] fit in a {where}, {busy} busy, "
              f"{a.seconds:g} s ...", file=sys.stderr, flush=True)
        rows.append(measure(where, busy, a.seconds))
    watchdog_ms = SafetyParams().watchdog_s * 1e3
    print("# A real-time loop beside the identification's fit\n")
    print(f"A 1 kHz loop under SCHED_FIFO {PRIORITY} on CPU {os.cpu_count() - 1} (GIL "
          f"switch interval {GIL_SWITCH_INTERVAL_S * 1e3:g} ms) while the "
          f"transfer system's fit runs back to back, {a.seconds:g} s per run, "
          f"{a.repeats} runs per case (each run's figures, run by run).  Lateness: each "
          f"wake after its deadline.  Stalls: cycles more than {STALL_CYCLES:g} periods "
          f"late; watchdog: more than the rig's {watchdog_ms:g} ms.\n")
    print("| fit in | spinning processes | fits | lateness p50 / p99 [ms] | longest [ms] | "
          "stalls | past the watchdog |")
    print("|---|---|---|---|---|---|---|")
    for where, busy in cases:
        mine = [r for r in rows if r["where"] == where and r["busy"] == busy]

        def each(key: str, fmt: str, runs: list[dict[str, Any]] = mine) -> str:
            return " / ".join(format(r[key], fmt) for r in runs)

        print(f"| {'a thread of the loop' if where == 'thread' else 'its own process'} | "
              f"{busy} | {each('fits', 'd')} | "
              + " ; ".join(f"{r['p50']:.2f} / {r['p99']:.2f}" for r in mine)
              + f" | {each('max', '.1f')} | {each('stalls', 'd')} | "
              f"{each('watchdog', 'd')} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
