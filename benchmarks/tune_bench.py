#!/usr/bin/env python3
"""Benchmark of ``damper-hil tune``; prints a markdown table.

1. **The reference case**: ``damper-hil tune --designs 1000`` (three ISO 8608 roads of 500 m
   at 20 m/s plus the pothole, two refinement rounds of 64) on a local cluster of 2
   workers, the whole command timed (cluster start, search, report and plots).  Target:
   at most 10 minutes on a 2-core machine.
2. **Scaling**: the search alone (``--scaling-designs``, no refinement) on dask's
   synchronous scheduler, a LocalCluster of 2 processes (started for each run) and a
   ``dask scheduler`` + 2 ``dask worker`` commands (started once); ``--repeats`` runs in
   turn.  Damper + quarter-car steps per second, speed-up and efficiency against the
   synchronous run of the same repeat, and the data shipped per task (pickled chunk).

Usage: ``python benchmarks/tune_bench.py [--designs 1000] [--scaling-designs 200]
[--repeats 2]``
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from machine import cpu_name

from damper_emulator.params import load_config
from damper_hil.engine import command_cluster, open_engine
from damper_hil.tune.runner import EvalTask, run_tune
from ride_sim import tuning as tu
from ride_sim.params import load_ride_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--designs", type=int, default=1000)
    ap.add_argument("--scaling-designs", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="tune_bench_"))
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "damper_hil.cli", "tune", "--out",
                          str(tmp / "full"), "--designs", str(args.designs), "--workers", "2"],
                         capture_output=True, text=True)
    full_s = time.perf_counter() - t0
    assert res.returncode == 0, res.stderr
    summary = res.stdout.strip().splitlines()[-1]

    base = load_config()
    ride = load_ride_config()
    dt = ride.simulation.step_s
    spec = tu.spec_from_mapping({"tune": {"designs": args.scaling_designs,
                                          "refine_rounds": 0}}, "bench")
    roads = tu.roads(spec.settings, ride.road, dt)
    steps = (args.scaling_designs + 1) * sum(r.heights.size for r in roads)
    import cloudpickle

    chunk = EvalTask(base, np.ones((spec.settings.chunk, len(spec.variables))), spec,
                     ride.quarter_car, ride.road, dt)
    shipped = len(cloudpickle.dumps(chunk))
    rates: dict[str, list[float]] = {"sync": [], "local2": [], "cmd2": []}
    with command_cluster(tmp, 2) as cluster:
        for _ in range(args.repeats):
            for key, engine in (("sync", {"workers": 1}), ("local2", {"workers": 2}),
                                ("cmd2", {"scheduler": cluster.address})):
                t0 = time.perf_counter()
                with open_engine(**engine) as eng:
                    run_tune(base, spec, ride.quarter_car, ride.road, dt, eng,
                             say=lambda m: None)
                rates[key].append(steps / (time.perf_counter() - t0))
    print(f"# damper-hil tune benchmark — {cpu_name()}")
    print()
    print(f"`damper-hil tune --designs {args.designs} --workers 2` (roads "
          f"{', '.join(r.name for r in roads)}), whole command: **{full_s:.0f} s** "
          "(target ≤ 600 s)")
    print()
    print(f"> {summary}")
    print()
    print(f"Scaling: {args.scaling_designs} designs + baseline, {steps / 1e6:.1f} M damper + "
          f"quarter-car steps per run, {args.repeats} repeats; a task ships "
          f"{shipped / 1e3:.0f} kB ({spec.settings.chunk} designs)")
    print()
    print("| engine | workers | M steps/s, median (range) | speed-up | efficiency |")
    print("|---|---|---|---|---|")
    for key, label, w in (("sync", "synchronous scheduler", 1),
                          ("local2", "LocalCluster (started for the run)", 2),
                          ("cmd2", "dask scheduler + dask worker commands", 2)):
        r = rates[key]
        speed = statistics.median([a / b for a, b in zip(r, rates["sync"])])
        print(f"| {label} | {w} | {statistics.median(r) / 1e6:.2f} ({min(r) / 1e6:.2f}–"
              f"{max(r) / 1e6:.2f}) | {speed:.2f} | {speed / w:.2f} |")


if __name__ == "__main__":
    main()
