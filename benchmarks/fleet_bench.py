#!/usr/bin/env python3
"""Benchmark of ``damper-hil fleet`` on Dask; prints a markdown table.

A virtual production batch (``fleet-example``, the paper's protocol unless ``--short``) is
run through :func:`damper_hil.fleet.runner.run_fleet` on three engines, each on a fresh
output folder, ``--repeats`` times in turn (so that machine noise spreads over all):

* dask's synchronous scheduler (1 worker, this process);
* a ``distributed.LocalCluster`` of 2 worker processes;
* a ``dask scheduler`` and 2 ``dask worker`` processes started as separate commands,
  reached by address.

Throughput is dampers per minute (median, with the range over the repeats), the engine's
start included (a local cluster is started for each run; the command cluster once, before
the timings); the speed-up and the efficiency (speed-up / workers) are against the
synchronous run of the same repeat.  The data shipped per task is the pickled size of a
damper's job.  With ``--diagnose`` it also times a fleet with ``--diagnose`` on the
2-worker local cluster (once; minutes).

Usage: ``python benchmarks/fleet_bench.py [--dampers 12] [--repeats 3] [--short]
[--diagnose]``
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from machine import cpu_name

from damper_emulator.params import load_config
from damper_hil.engine import command_cluster, open_engine
from damper_hil.fleet.example import write_example
from damper_hil.fleet.inputs import find_dampers
from damper_hil.fleet.runner import load_job, run_fleet


def timed(data: Path, out: Path, **engine) -> tuple[float, float]:
    """Seconds of one fleet run, the engine's start included, and of the start alone."""
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    with open_engine(**engine) as eng:
        started = time.perf_counter() - t0
        run = run_fleet(data, out, eng, say=lambda m: None)
    dt = time.perf_counter() - t0
    bad = [r["id"] for r in run.rows if r["status"] != "ok"]
    assert not bad, bad
    return dt, started


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dampers", type=int, default=12)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--short", action="store_true")
    ap.add_argument("--diagnose", action="store_true")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="fleet_bench_"))
    data = tmp / "batch"
    write_example(data, load_config(), args.dampers, seed=0, short=args.short,
                  say=lambda m: None)
    import cloudpickle

    shipped = statistics.median(len(cloudpickle.dumps(load_job(d, False, None)))
                                for d in find_dampers(data))
    n = args.dampers
    rates: dict[str, list[float]] = {"sync": [], "local2": [], "cmd2": []}
    starts: dict[str, list[float]] = {k: [] for k in rates}
    with command_cluster(tmp, 2) as cluster:
        address = cluster.address
        timed(data, tmp / "warm", workers=1)  # numba's cache filled before any timing
        for _ in range(args.repeats):
            for key, engine in (("sync", {"workers": 1}), ("local2", {"workers": 2}),
                                ("cmd2", {"scheduler": address})):
                dt, start = timed(data, tmp / key, **engine)
                rates[key].append(n / dt * 60.0)
                starts[key].append(start)
    print(f"# damper-hil fleet benchmark — {cpu_name()}, "
          f"{os.cpu_count()} CPUs")
    print()
    print(f"{n} dampers, {'short' if args.short else 'paper'} protocol, identify + validate "
          f"per damper; {args.repeats} repeats; data shipped per task (pickled job) "
          f"{shipped / 1e6:.2f} MB")
    print()
    print("| engine | workers | dampers/min, median (range) | speed-up | efficiency | "
          "engine start [s] |")
    print("|---|---|---|---|---|---|")
    base = rates["sync"]
    for key, label, w in (("sync", "synchronous scheduler", 1),
                          ("local2", "LocalCluster (processes)", 2),
                          ("cmd2", "dask scheduler + dask worker commands", 2)):
        speed = [r / b for r, b in zip(rates[key], base)]
        print(f"| {label} | {w} | {statistics.median(rates[key]):.1f} "
              f"({min(rates[key]):.1f}–{max(rates[key]):.1f}) | "
              f"{statistics.median(speed):.2f} | {statistics.median(speed) / w:.2f} | "
              f"{statistics.median(starts[key]):.2f} |")
    if args.diagnose:
        out = tmp / "diag"
        t0 = time.perf_counter()
        with open_engine(workers=2) as eng:
            run = run_fleet(data, out, eng, diagnose=True, say=lambda m: None)
        dt = time.perf_counter() - t0
        fams = [r.get("diagnosis_family") for r in run.rows]
        print()
        print(f"`--diagnose`, all nine candidates, LocalCluster of 2 workers: {n} dampers in "
              f"{dt:.0f} s ({dt / n:.0f} s per damper); diagnoses: "
              + ", ".join(f"{r['id']} {f}" for r, f in zip(run.rows, fams)))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
