#!/usr/bin/env python3
"""The closed-loop demo's real-time figures over several runs, beside the host's own floor;
prints a markdown table.

Each run is ``damper-hil demo`` in its own process (the first with an empty numba cache
when ``--cold``), and the figures come from its ``demo.json``:

* the ride loop's real-time factor (samples advanced over the time between its first and
  last tick);
* the emulator's loop from its first input on: p99 of |period − 1 ms|, overruns (periods
  over 2 ms) and the longest period;
* fault outputs between the first input and the ride's end;
* the model's warm-up before 'active' and the kernels compiled after it (must be 0).

With ``--cyclictest`` (Debian's ``rt-tests``), ``cyclictest`` runs beside each demo's ride
at the emulator's settings (SCHED_FIFO 80, 1 kHz, ``/dev/cpu_dma_latency`` 0): its wake-ups
later than 1 ms are the host stopping the VM, which no process inside it can avoid; the
emulator's overruns are to be read against them.  Targets (issue 14): real-time factor
>= 0.99, no overrun after ready, p99 period error <= 100 µs, no fault outputs after the
first input.

Usage: ``python benchmarks/demo_bench.py [--runs N] [--duration S] [--cold] [--cyclictest]
[--json FILE]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from machine import cpu_name

ROOT = Path(__file__).resolve().parent.parent
#: cyclictest's histogram range [µs]; later wake-ups are counted as overflows
HISTOGRAM_US = 3000
#: A wake-up this late is a missed period of a 1 kHz loop [µs]
LATE_US = 1000
#: Seconds after the demo's start when the ride runs (start-up and warm-up come first)
RIDE_START_S = 12.0


def _cyclictest(seconds: float, histfile: Path) -> subprocess.Popen:
    loops = int(seconds * 1000)
    return subprocess.Popen(["cyclictest", "-m", "-p", "80", "-i", "1000", "-l", str(loops),
                             "-q", "-t", "1", "-h", str(HISTOGRAM_US),
                             f"--histfile={histfile}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _late_wakeups(histfile: Path) -> tuple[int, int, float]:
    """(wake-ups later than LATE_US, total, p99 [µs]) of a cyclictest histogram."""
    rows, overflows = [], 0
    for line in histfile.read_text().splitlines():
        if line.startswith("# Histogram Overflows:"):
            overflows = int(line.split(":")[1])
        elif line and not line.startswith("#"):
            parts = line.split()
            rows.append((int(parts[0]), int(parts[1])))
    lat = np.array([r[0] for r in rows])
    n = np.array([r[1] for r in rows])
    total = int(n.sum()) + overflows
    cum = np.cumsum(n) / max(total, 1)
    p99 = float(lat[np.searchsorted(cum, 0.99)]) if total else float("nan")
    return int(n[lat > LATE_US].sum()) + overflows, total, p99


def run(args) -> list[dict]:
    results = []
    cache = Path(tempfile.mkdtemp(prefix="demo-bench-cache-")) if args.cold else None
    have_cyclictest = args.cyclictest and shutil.which("cyclictest") is not None
    if args.cyclictest and not have_cyclictest:
        print("cyclictest not found (Debian: rt-tests): host floor not measured",
              file=sys.stderr)
    for k in range(args.runs):
        out = Path(tempfile.mkdtemp(prefix="demo-bench-"))
        env = dict(os.environ)
        if cache is not None:
            env["NUMBA_CACHE_DIR"] = str(cache)   # empty for the first run: cold
        cyc = None
        hist = out / "cyclictest.txt"
        started = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "damper_emulator.cli", "demo",
                                 "--duration", str(args.duration), "--out", str(out / "demo")],
                                cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        if have_cyclictest:
            time.sleep(RIDE_START_S)
            cyc = _cyclictest(args.duration * 0.75, hist)
        log, _ = proc.communicate()
        wall = time.monotonic() - started
        if cyc is not None:
            cyc.wait()
        if proc.returncode != 0:
            print(f"run {k + 1}: demo failed (exit {proc.returncode}): "
                  f"{log.strip().splitlines()[-1] if log.strip() else ''}", file=sys.stderr)
            results.append({"run": k + 1, "failed": True})
            continue
        doc = json.loads((out / "demo" / "demo.json").read_text())
        loop = doc.get("emulator_loop") or {}
        after = loop.get("after_first_input") or {}
        row = {"run": k + 1, "cold": bool(cache is not None and k == 0),
               "wall_s": round(wall, 1),
               "real_time_factor": doc["ride"].get("real_time_factor"),
               "p99_error_us": after.get("period_error_p99_us"),
               "overruns": after.get("overruns"),
               "period_max_ms": (after.get("period_max_us") or float("nan")) / 1e3,
               "faults_in_ride": doc.get("fault_outputs_after_first_input"),
               "warm_up_s": loop.get("warm_up_s"),
               "compiled_after_ready": doc.get("kernels_compiled_after_ready")}
        if cyc is not None and hist.is_file():
            late, total, p99 = _late_wakeups(hist)
            row.update(host_late_wakeups=late, host_samples=total, host_p99_us=p99)
        results.append(row)
        shutil.rmtree(out, ignore_errors=True)
    if cache is not None:
        shutil.rmtree(cache, ignore_errors=True)
    return results


def _spread(values) -> str:
    v = [x for x in values if x is not None and x == x]
    if not v:
        return "–"
    return f"{min(v):.4g} … {statistics.median(v):.4g} … {max(v):.4g}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="demo runs (default 3)")
    ap.add_argument("--duration", type=float, default=20.0, help="ride seconds (default 20)")
    ap.add_argument("--cold", action="store_true",
                    help="the first run with an empty numba cache (a fresh NUMBA_CACHE_DIR)")
    ap.add_argument("--cyclictest", action="store_true",
                    help="measure the host's wake-up floor beside each ride (rt-tests)")
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args()
    if args.runs < 1 or not args.duration > 0:
        ap.error("--runs must be at least 1 and --duration positive")
    rows = run(args)
    print(f"# demo real-time figures: {cpu_name()}, {os.cpu_count()} CPUs, Python "
          f"{platform.python_version()}, {time.strftime('%Y-%m-%d %H:%M')}; "
          f"{args.duration:g} s ride per run")
    print()
    host = any("host_late_wakeups" in r for r in rows)
    head = ("| run | real-time factor | p99 period error [µs] | overruns | max period [ms] "
            "| faults in ride | warm-up [s] | compiled after ready |")
    if host:
        head += " host: wake-ups > 1 ms / p99 [µs] |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for r in rows:
        if r.get("failed"):
            print(f"| {r['run']} | failed |")
            continue
        line = (f"| {r['run']}{' (cold)' if r['cold'] else ''} | {r['real_time_factor']} | "
                f"{r['p99_error_us']:.0f} | {r['overruns']} | {r['period_max_ms']:.1f} | "
                f"{r['faults_in_ride']} | {r['warm_up_s']:.2f} | {r['compiled_after_ready']} |")
        if host:
            line += f" {r.get('host_late_wakeups', '–')} / {r.get('host_p99_us', '–')} |"
        print(line)
    ok = [r for r in rows if not r.get("failed")]
    print()
    print(f"spread (min … median … max) over {len(ok)} runs: real-time factor "
          f"{_spread([r['real_time_factor'] for r in ok])}; p99 period error "
          f"{_spread([r['p99_error_us'] for r in ok])} µs; overruns "
          f"{_spread([r['overruns'] for r in ok])}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 1 if any(r.get("failed") for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
