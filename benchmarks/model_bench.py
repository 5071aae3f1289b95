#!/usr/bin/env python3
"""Benchmark of the damper physics core; prints a markdown table.

* one real-time step called from Python (``DamperStepper.step``): median / p99 per call;
* batch simulation (``simulate``) of the paper's chirp at 1 kHz: damper steps per second;
* model load (parameter validation + inverse valve tables).

Targets: real-time step median <= 10 µs; batch >= 1,000,000 steps/s on one core.

Usage: ``python benchmarks/model_bench.py [--calls N] [--repeats N]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
from machine import cpu_name

from damper_emulator.dyno.protocols import chirp
from damper_emulator.model.compressible import DamperModel, DamperStepper, simulate
from damper_emulator.params import load_config


def bench_step(model: DamperModel, calls: int) -> tuple[float, float, float]:
    _t, x, v = chirp(0.5, 16.0, duration_s=calls / 1000.0, v_start_m_s=0.05, v_end_m_s=1.5,
                    rate_hz=1000.0)
    stepper = DamperStepper(model, x[0], v[0])
    xs, vs = x.tolist(), v.tolist()
    step = stepper.step
    clock = time.perf_counter_ns
    times = np.empty(len(xs) - 1)
    for i in range(1, len(xs)):
        t0 = clock()
        step(xs[i], vs[i], 1e-3)
        times[i - 1] = clock() - t0
    us = times / 1000.0
    return float(np.median(us)), float(np.percentile(us, 99)), float(us.max())


def bench_batch(model: DamperModel, repeats: int, rate_hz: float) -> float:
    t, x, v = chirp(rate_hz=rate_hz)  # the paper's chirp: 0.5–16 Hz, 60 s
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        simulate(model, t, x, v)
        rates.append(t.size / (time.perf_counter() - t0))
    return statistics.median(rates)


def bench_load(repeats: int) -> float:
    from damper_emulator.model.valve_table import _build_table

    times = []
    for _ in range(repeats):
        _build_table.cache_clear()
        t0 = time.perf_counter()
        DamperModel(load_config())
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1000.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=100_000, help="real-time step calls")
    ap.add_argument("--repeats", type=int, default=7, help="batch repetitions (median)")
    args = ap.parse_args()

    t0 = time.perf_counter()
    model = DamperModel()
    simulate(model, [0.0, 1e-3], [0.0, 1e-5], [0.0, 1e-2])  # compile / load the JIT cache
    warm = time.perf_counter() - t0

    med, p99, worst = bench_step(model, args.calls)
    batch_1k = bench_batch(model, args.repeats, 1000.0)
    batch_10k = bench_batch(model, max(1, args.repeats // 2), 10_000.0)
    load_ms = bench_load(args.repeats)

    print(f"# damper-hil model benchmark — {cpu_name()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}")
    print()
    print("| measure | result | target |")
    print("|---|---|---|")
    print(f"| real-time step from Python, median | {med:.2f} µs ({med / 10:.2f} % of a 1 kHz "
          f"cycle) | ≤ 10 µs |")
    print(f"| real-time step from Python, p99 / max | {p99:.2f} / {worst:.1f} µs | – |")
    print(f"| batch, paper chirp at 1 kHz (2 BDF2 sub-steps per step) | "
          f"{batch_1k / 1e6:.2f} M steps/s ({batch_1k / 1e3:,.0f}× real time) | ≥ 1.0 M steps/s |")
    print(f"| batch, paper chirp at 10 kHz (1 sub-step per step) | "
          f"{batch_10k / 1e6:.2f} M steps/s ({batch_10k / 1e4:,.0f}× real time) | – |")
    print(f"| model load (validate + valve tables) | {load_ms:.1f} ms | – |")
    print(f"| first call incl. JIT compile or cache load | {warm:.2f} s | – |")


if __name__ == "__main__":
    main()
