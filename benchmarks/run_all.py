#!/usr/bin/env python3
"""Run the benchmarks in turn and write their tables into one page (``make bench``).

Each benchmark is a script of this directory that prints markdown; this driver runs them
one after another as processes of their own (so that none shares its cores or its imports
with another), echoes what they print, and puts each one's output between
``<!-- NAME -->`` and ``<!-- /NAME -->`` in the page given by ``--doc`` (a section that is
missing is added at the page's end; the rest of the page is kept as it is). The machine
the run was made on heads the generated part, between ``<!-- machine -->`` markers.

A benchmark that fails keeps its old section, and the driver exits 1 after the others ran.

Usage: ``python benchmarks/run_all.py [--doc docs/performance.md] [--only NAME ...]
[--list]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

from machine import cpu_name

HERE = Path(__file__).resolve().parent

#: what ``make bench`` runs, in this order, with these arguments
BENCHMARKS: dict[str, tuple[str, ...]] = {
    "model_bench": (),
    "message_bench": (),
    "identify_bench": (),
    "ride_bench": (),
    "many_bench": (),
    "fleet_bench": (),
    "tune_bench": (),
    "node_bench": (),
    "replay_bench": (),
    "can_bench": (),
    "demo_bench": ("--runs", "3", "--host"),
    "hybrid_bench": ("--repeats", "2", "--twin-chain"),
    "offloop_bench": (),
}
#: run only when named with ``--only`` (a long run: every truth scenario's diagnosis)
BY_NAME_ONLY: dict[str, tuple[str, ...]] = {"diagnose_bench": ()}


def machine() -> str:
    """One line: the CPU, its count and the Python that ran the benchmarks."""
    return (f"Measured on {cpu_name()}, {os.cpu_count()} CPUs, Python "
            f"{sys.version.split()[0]}; each benchmark in a process of its own, one after "
            f"another.")


def markers(name: str) -> tuple[str, str]:
    return f"<!-- {name} -->", f"<!-- /{name} -->"


def write_section(path: Path, name: str, text: str) -> None:
    """``text`` between the markers of ``name`` in ``path`` (appended when absent)."""
    begin, end = markers(name)
    old = path.read_text(encoding="utf-8") if path.exists() else ""
    block = f"{begin}\n{text.strip()}\n{end}\n\n"
    if begin in old and end in old:
        head, rest = old.split(begin, 1)
        new = head + block + rest.split(end, 1)[1].lstrip("\n")
    else:
        new = (old.rstrip() + "\n\n" if old.strip() else "") + block
    path.write_text(new, encoding="utf-8")


def as_section(output: str) -> str:
    """A benchmark's output as a section of the page: its headings two levels down (the
    page's results are a level-2 section)."""
    lines = output.strip().splitlines()
    return "\n".join("##" + line if line.startswith("#") else line for line in lines)


def run_one(name: str, args: tuple[str, ...]) -> tuple[int, str, float]:
    """Run ``name`` with ``args``: its exit code, what it printed, its wall time [s]."""
    cmd = [sys.executable, str(HERE / f"{name}.py"), *args]
    print(f"\n=== {name} {' '.join(args)}", flush=True)
    t0 = time.perf_counter()
    with subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=HERE.parent) as proc:
        assert proc.stdout is not None
        out = []
        for line in proc.stdout:
            sys.stdout.write(line)
            sys.stdout.flush()
            out.append(line)
        rc = proc.wait()
    return rc, "".join(out), time.perf_counter() - t0


def main() -> int:
    every = {**BENCHMARKS, **BY_NAME_ONLY}
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--doc", type=Path, default=None, help="the page to write the tables in")
    ap.add_argument("--only", nargs="+", choices=sorted(every), metavar="NAME",
                    help=f"run only these (of {', '.join(every)})")
    ap.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    args = ap.parse_args()
    if args.list:
        for name, extra in every.items():
            print(name, *extra)
        return 0
    chosen = {n: every[n] for n in args.only} if args.only else BENCHMARKS
    failed = []
    for name, extra in chosen.items():
        rc, out, wall = run_one(name, extra)
        print(f"=== {name}: exit {rc} in {wall:.0f} s", flush=True)
        if rc != 0 or not out.strip():
            failed.append(name)
        elif args.doc is not None:
            write_section(args.doc, "machine", machine())
            write_section(args.doc, name, as_section(out))
    if failed:
        print(f"failed: {', '.join(failed)} (their sections were left as they were)",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
