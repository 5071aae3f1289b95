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
* the emulator's time from its launch to 'active' (its own log's stamp; the demo's
  probe may see it a DDS discovery round later), the model's warm-up before 'active' and
  the kernels compiled after it (must be 0).

With ``--host``, :mod:`host_sentinel` runs one SCHED_FIFO thread pinned to each CPU at the
emulator's priority, waking every millisecond, for the whole run: its wake-ups later than
1 ms are the machine stopping (on a VM, the hypervisor stopping a vCPU), which no process
can avoid.  Each overrun of the emulator's loop is then classed by whether a sentinel was
stalled during it (``host``) or not (``own``): the loop's own overruns are the ones to fix.
Targets: real-time factor >= 0.99, no overrun after ready, p99 period error
<= 100 µs, no fault outputs after the first input, the emulator active <= 2 s after its
launch (warm runs).

Usage: ``python benchmarks/demo_bench.py [--runs N] [--duration S] [--cold] [--host]
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
#: Seconds the sentinels run beyond the ride (start-up, warm-up, shut-down); they are
#: stopped when the demo ends
SENTINEL_MARGIN_S = 120.0
SENTINEL = ROOT / "benchmarks" / "host_sentinel.py"
#: the targets of the module docstring
TARGET_RTF = 0.99
TARGET_P99_ERROR_US = 100.0
TARGET_ACTIVE_S = 2.0


def _start_sentinels(seconds: float, out: Path) -> list[tuple[subprocess.Popen, Path]]:
    procs = []
    for cpu in sorted(os.sched_getaffinity(0)):
        path = out / f"sentinel_{cpu}.npy"
        procs.append((subprocess.Popen([sys.executable, str(SENTINEL), str(cpu),
                                        str(seconds), str(path)]), path))
    return procs


def _stop_sentinels(procs) -> np.ndarray | None:
    """The stalls ``(start_ns, end_ns)`` every sentinel saw, or None when none ran."""
    events = []
    for proc, path in procs:
        proc.terminate()
        proc.wait()
        if path.is_file():
            events.append(np.load(path))
    return np.concatenate(events) if events else None


def classify_overruns(record: dict, stalls: np.ndarray) -> tuple[int, int]:
    """``(host, own)``: the loop's overruns from its first input on during which some
    sentinel was stalled, and the others."""
    periods = record["periods_ns"].astype(np.int64)
    if periods.size < int(record["ticks"]) - 1 or not int(record.get("first_tick_ns", 0)):
        return 0, 0                                   # ring wrapped or no time base
    ticks = int(record["first_tick_ns"]) + np.concatenate([[0], np.cumsum(periods)])
    first = max(0, int(record.get("first_input_tick", 0)))
    host = own = 0
    for k in np.nonzero(periods > 2 * int(record["period_ns"]))[0]:
        if k < first:
            continue
        a, b = ticks[k], ticks[k + 1]
        if stalls.size and np.any((stalls[:, 0] < b) & (stalls[:, 1] > a)):
            host += 1
        else:
            own += 1
    return host, own


def run(args) -> list[dict]:
    results = []
    cache = Path(tempfile.mkdtemp(prefix="demo-bench-cache-")) if args.cold else None
    for k in range(args.runs):
        out = Path(tempfile.mkdtemp(prefix="demo-bench-"))
        env = dict(os.environ)
        if cache is not None:
            env["NUMBA_CACHE_DIR"] = str(cache)   # empty for the first run: cold
        sentinels = (_start_sentinels(args.duration + SENTINEL_MARGIN_S, out)
                     if args.host else [])
        started = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "damper_hil.cli", "demo",
                                 "--duration", str(args.duration), "--out", str(out / "demo")],
                                cwd=ROOT, env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        log, _ = proc.communicate()
        wall = time.monotonic() - started
        stalls = _stop_sentinels(sentinels)
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
               "active_after_s": doc.get("emulator_active_after_s"),
               "compiled_after_ready": doc.get("kernels_compiled_after_ready")}
        if stalls is not None:
            with np.load(out / "demo" / "emulator_loop.npz") as z:
                record = {k: z[k] for k in z.files}
            host, own = classify_overruns(record, stalls)
            row.update(host_stalls=int(stalls.shape[0]), overruns_host=host,
                       overruns_own=own)
        results.append(row)
        shutil.rmtree(out, ignore_errors=True)
    if cache is not None:
        shutil.rmtree(cache, ignore_errors=True)
    return results


def _num(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


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
    ap.add_argument("--host", action="store_true",
                    help="one stall sentinel per CPU beside each run (host_sentinel.py): "
                         "class the loop's overruns as the machine's or its own")
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args()
    if args.runs < 1 or not args.duration > 0:
        ap.error("--runs must be at least 1 and --duration positive")
    rows = run(args)
    print(f"# demo real-time figures: {cpu_name()}, {os.cpu_count()} CPUs, Python "
          f"{platform.python_version()}; "
          f"{args.duration:g} s ride per run")
    print()
    host = any("host_stalls" in r for r in rows)
    head = ("| run | real-time factor | p99 period error [µs] | overruns | max period [ms] "
            "| faults in ride | active after launch [s] | warm-up [s] | compiled after ready |")
    if host:
        head += " sentinel stalls > 1 ms | overruns during one / not |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for r in rows:
        if r.get("failed"):
            print(f"| {r['run']} | failed |")
            continue
        line = (f"| {r['run']}{' (cold)' if r['cold'] else ''} | {r['real_time_factor']} | "
                f"{r['p99_error_us']:.0f} | {r['overruns']} | {r['period_max_ms']:.1f} | "
                f"{r['faults_in_ride']} | {_num(r['active_after_s'])} | {r['warm_up_s']:.2f} | "
                f"{r['compiled_after_ready']} |")
        if host:
            line += (f" {r.get('host_stalls', '–')} | {r.get('overruns_host', '–')} / "
                     f"{r.get('overruns_own', '–')} |")
        print(line)
    ok = [r for r in rows if not r.get("failed")]
    print()
    print(f"spread (min … median … max) over {len(ok)} runs: real-time factor "
          f"{_spread([r['real_time_factor'] for r in ok])}; p99 period error "
          f"{_spread([r['p99_error_us'] for r in ok])} µs; overruns "
          f"{_spread([r['overruns'] for r in ok])}; emulator active after launch "
          f"{_spread([r['active_after_s'] for r in ok if not r['cold']])} s (warm runs)")
    print()
    for what, holds, runs in _verdicts(ok):
        print(f"- {what}: met in {holds} of {runs} runs{'' if holds == runs else ': NOT met'}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 1 if any(r.get("failed") for r in rows) else 0


def _verdicts(ok: list[dict]) -> list[tuple[str, int, int]]:
    """Each target of the module docstring: how many runs hold it, of how many."""
    warm = [r for r in ok if not r["cold"]]
    checks = [
        (f"real-time factor ≥ {TARGET_RTF:g}", ok, lambda r: r["real_time_factor"] >= TARGET_RTF),
        ("no overrun", ok, lambda r: r["overruns"] == 0),
        (f"p99 period error ≤ {TARGET_P99_ERROR_US:g} µs", ok,
         lambda r: r["p99_error_us"] <= TARGET_P99_ERROR_US),
        ("no fault output in the ride", ok, lambda r: r["faults_in_ride"] == 0),
        (f"emulator active ≤ {TARGET_ACTIVE_S:g} s after its launch (warm runs)", warm,
         lambda r: r["active_after_s"] is not None and r["active_after_s"] <= TARGET_ACTIVE_S),
    ]
    return [(what, sum(1 for r in runs if test(r)), len(runs)) for what, runs, test in checks
            if runs]


if __name__ == "__main__":
    sys.exit(main())
