#!/usr/bin/env python3
"""Benchmark of ``damper-hil replay`` as a user runs it; prints a markdown table.

Each run is ``damper-hil replay BAG --out DIR`` in a process of its own (the console
entry, as a user types it), on the shipped bag ``bags/demo_5s`` by default; the figures
come from its ``replay.json``:

* the whole command (``command_s``: from the process's start until its JSON is written)
  and the wall time this benchmark saw (process start to exit);
* the replay proper (``elapsed_s``: reading the bag, the model, writing the output bag and
  the comparison) and its speed against real time;
* the model's part of it (``compute_s``: matching the inputs and the compiled batch loop)
  and its speed against real time;
* the set-up (``setup_s``: the model, the typestore, loading the compiled code) and the
  plot.

The first run loads the compiled code from numba's cache as every run does (``make``'s
install fills it); it is shown, not left out.  Targets: the whole command <= 2 s, the
model >= 1000 x real time.

Usage: ``python benchmarks/replay_bench.py [--runs N] [--bag DIR] [--json FILE]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import cpu_name

ROOT = Path(__file__).resolve().parent.parent
TARGET_COMMAND_S = 2.0
TARGET_COMPUTE_SPEED = 1000.0


def run_once(bag: Path, out: Path) -> dict:
    """One replay as a process; its ``replay.json`` with the wall time seen here."""
    started = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "damper_hil.cli", "replay", str(bag),
                           "--out", str(out)], cwd=ROOT, capture_output=True, text=True)
    wall = time.monotonic() - started
    if proc.returncode != 0:
        raise SystemExit(f"replay failed (exit {proc.returncode}): "
                         f"{proc.stderr.strip().splitlines()[-1:]}")
    doc = json.loads((out / "replay.json").read_text())
    doc["wall_s"] = wall
    return doc


def _spread(values: list[float]) -> str:
    return f"{min(values):.3g} … {statistics.median(values):.3g} … {max(values):.3g}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="replays (default 5)")
    ap.add_argument("--bag", type=Path, default=ROOT / "bags" / "demo_5s")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args()
    if args.runs < 1:
        ap.error("--runs must be at least 1")
    with tempfile.TemporaryDirectory() as tmp:
        rows = [run_once(args.bag, Path(tmp) / f"r{k}") for k in range(args.runs)]
    first = rows[0]
    print(f"# damper-hil replay: {cpu_name()}, {os.cpu_count()} CPUs, Python "
          f"{platform.python_version()}; bag {args.bag.name}: {first['forces']} forces, "
          f"{first['recorded_duration_s']:.1f} s recorded, {first['trigger']} trigger\n")
    print("| run | whole command [s] | wall seen here [s] | replay proper [ms] (× real "
          "time) | the model [ms] (× real time) | set-up [s] | plot [s] |")
    print("|---|---|---|---|---|---|---|")
    for k, r in enumerate(rows, 1):
        print(f"| {k} | {r['command_s']:.2f} | {r['wall_s']:.2f} | "
              f"{r['elapsed_s'] * 1e3:.0f} ({r['speed_vs_real_time']:.0f}) | "
              f"{r['compute_s'] * 1e3:.1f} ({r['compute_speed_vs_real_time']:.0f}) | "
              f"{r['setup_s']:.2f} | {r['timings_s'].get('plot', float('nan')):.2f} |")
    command = [r["command_s"] for r in rows]
    speed = [r["compute_speed_vs_real_time"] for r in rows]
    print(f"\nspread (min … median … max) over {len(rows)} runs: whole command "
          f"{_spread(command)} s; the model {_spread(speed)} × real time; replay proper "
          f"{_spread([r['speed_vs_real_time'] for r in rows])} × real time.")
    print(f"Targets: the whole command ≤ {TARGET_COMMAND_S:g} s "
          f"({'met' if statistics.median(command) <= TARGET_COMMAND_S else 'NOT met'} by "
          f"the median), the model ≥ {TARGET_COMPUTE_SPEED:g} × real time "
          f"({'met' if statistics.median(speed) >= TARGET_COMPUTE_SPEED else 'NOT met'} by "
          "the median).")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
