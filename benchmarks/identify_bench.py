#!/usr/bin/env python3
"""Benchmark of identification on the paper's protocol; prints a markdown table.

Virtual-dyno data of the sport damper with 4 N force noise: quasi-static 150 s at 50 Hz and
chirp 60 s at 1 kHz.  Target: identification in ≤ 10 s wall on one core.

Usage: ``python benchmarks/identify_bench.py [--repeats N]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from machine import cpu_name

from damper_emulator.dyno import protocols
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.identify.pipeline import identify
from damper_emulator.model.compressible import DamperModel, simulate
from damper_emulator.params import load_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cfg = load_config()
    model = DamperModel(cfg)
    rng = np.random.default_rng(0)
    data = []
    for t, x, v in (protocols.quasi_static(), protocols.chirp()):
        r = simulate(model, t, x, v)
        data.append(MeasuredData(t, x, r.force_n + rng.normal(0.0, 4.0, t.size), v))
    identify(*data, cfg)  # JIT warm-up
    times, result = [], None
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        result = identify(*data, cfg)
        times.append(time.perf_counter() - t0)
    d, d0 = result.config.damper, cfg.damper
    errors = [abs(getattr(d, k) / getattr(d0, k) - 1) for k in
              ("gas_pressure_static_pa", "gas_volume_static_m3", "friction_force_n")]
    for side in ("rebound", "compression"):
        errors += list(np.abs(np.array(tuple(getattr(d, side)))
                              / np.array(tuple(getattr(d0, side))) - 1))
    print(f"# damper-hil identification benchmark — {cpu_name()}")
    print()
    print("| measure | result | target |")
    print("|---|---|---|")
    print(f"| identify, paper protocol (QS 7,501 + chirp 60,001 samples), median of "
          f"{args.repeats} | {statistics.median(times):.2f} s | ≤ 10 s |")
    print(f"| quasi-static ↔ chirp rounds | {result.rounds} | – |")
    print(f"| worst parameter error (13 parameters, 4 N noise) | {100 * max(errors):.2f} % | "
          "≤ 5 % |")
    print(f"| fit r.m.s. quasi-static / rebound / compression | {result.quasi_static.rms:.2f} / "
          f"{result.rebound.rms:.2f} / {result.compression.rms:.2f} N | noise 4 N |")


if __name__ == "__main__":
    main()
