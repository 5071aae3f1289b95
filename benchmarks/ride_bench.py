#!/usr/bin/env python3
"""Benchmark of the ride studies (ride_sim.study); prints a markdown table.

* one ride run: 500 m of the minor road at 20 m/s with the compressible (hysteretic) damper
  stepped at 1 kHz (25,001 steps), after JIT warm-up: the simulation alone, and the whole
  run as the studies do it (road synthesis, 3 s lead-in, simulation, Wk weighting, metrics);
  median of ``--repeats`` runs;
* the figure-11 speed sweep: 7 speeds x 3 dampers x 5 seeds (105 runs of 500 m) in a
  process pool on all cores, wall time including the pool start-up;
* figure 10 (5 seeds x 4 dampers, one process).

Targets: one run <= 0.5 s; the sweep <= 60 s using all cores.

Usage: ``python benchmarks/ride_bench.py [--repeats N] [--workers N]``
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
from machine import cpu_name


def _median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7, help="repetitions of one run (median)")
    ap.add_argument("--workers", type=int, default=None,
                    help="sweep worker processes (default: all cores)")
    args = ap.parse_args()

    t0 = time.perf_counter()
    from ride_sim import study, study_runs, study_setup
    from ride_sim.params import load_ride_config
    from ride_sim.quarter_car import simulate
    from ride_sim.road_synthesis import random_road

    cfg = load_ride_config()
    settings = study_setup.StudySettings.from_config(cfg)
    car, road, dt = settings.car, settings.road, settings.dt_s
    damper = study_setup.make_representation("nonlinear", car)
    heights = random_road(road.roughness, road.waviness, 500.0,
                          band_cycles_per_m=road.band_cycles_per_m, spacing_m=20.0 * dt,
                          seed=0).height_m
    simulate(car, damper, heights[:100], dt)            # JIT: compile or load the cache
    warm = time.perf_counter() - t0

    sim_s = _median_time(lambda: simulate(car, damper, heights, dt), args.repeats)

    def whole_run():
        h, n_lead, n_eval = study_runs.random_road_input(road, 20.0, 1, dt)
        res = study_runs.run(car, damper, h, dt)
        study_runs.metrics(res, n_lead, n_lead + n_eval)

    whole_run()
    run_s = _median_time(whole_run, args.repeats)
    n_run = int(round(road.lead_in_s / dt)) + heights.size

    workers = args.workers or os.cpu_count() or 1
    t0 = time.perf_counter()
    sweep = study.figure11(settings, workers=workers).doc
    sweep_s = time.perf_counter() - t0

    t0 = time.perf_counter()
    study.figure10(settings, keep_traces=False)
    fig10_s = time.perf_counter() - t0

    print(f"# damper-hil ride-study benchmark — {cpu_name()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}, numpy "
          f"{np.__version__}")
    print()
    print("| measure | result | target |")
    print("|---|---|---|")
    print(f"| 500 m at 20 m/s, compressible damper at 1 kHz ({heights.size} steps), "
          f"simulation, median of {args.repeats} | {sim_s * 1e3:.1f} ms "
          f"({heights.size / sim_s / 1e6:.2f} M steps/s, {heights.size * dt / sim_s:,.0f}× real "
          f"time) | ≤ 0.5 s |")
    print(f"| same, whole study run (road synthesis, 3 s lead-in, {n_run} steps, Wk, "
          f"metrics) | {run_s * 1e3:.1f} ms | – |")
    print(f"| speed sweep, {len(sweep['speeds_m_s'])} speeds × "
          f"{len(sweep['representations'])} dampers × {road.seeds} seeds = {sweep['runs']} "
          f"runs ({sweep['steps'] / 1e6:.2f} M steps), {workers} worker processes, wall | "
          f"{sweep_s:.2f} s (CPU in runs {sweep['cpu_s']:.2f} s) | ≤ 60 s |")
    print(f"| figure 10: {road.seeds} seeds × 4 dampers + exact-linear reference, one "
          f"process (14-speed table already built) | {fig10_s:.2f} s | – |")
    print(f"| first call incl. imports and JIT compile or cache load | {warm:.2f} s | – |")


if __name__ == "__main__":
    main()
