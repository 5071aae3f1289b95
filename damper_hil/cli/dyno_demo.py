"""``damper-hil dyno-demo``."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from damper_emulator.dyno.protocols import PAPER_SINES, Chirp
from damper_hil.cli.common import Formatter, load_model, positive_float, say_wrote, write_json


def add_parser(sub) -> None:
    dyno_demo = sub.add_parser(
        "dyno-demo", formatter_class=Formatter,
        help="virtual-dyno demonstration (the paper's tests on the sport damper)",
        description="Virtual-dyno demonstration on the 'sport' damper (config/sport.yaml):\n"
                    "the quasi-static test, the chirp, the paper's validation sines\n"
                    "(1 Hz / 0.05 m, 3 Hz / 0.05 m, 12 Hz / 0.005 m) with an overlay plot\n"
                    "(paper_sines.png) and the 14-speed test; writes demo.json.")
    dyno_demo.add_argument("--duration", metavar="S", type=positive_float,
                           default=Chirp.duration_s,
                           help=f"chirp duration [s] (default: {Chirp.duration_s:g})")
    # not the HIL demo's demo_out/: both write a demo.json
    dyno_demo.add_argument("--out", metavar="DIR", type=Path, default=Path("dyno_demo_out"),
                           help="output directory (created if missing; default: "
                                "dyno_demo_out)")
    dyno_demo.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.dyno import plots, runner
    from damper_emulator.dyno.measured import read_measured_csv

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    model, params_file = load_model(None)
    steps = 4 + len(PAPER_SINES)
    results: dict[str, Any] = {}
    files: list[str] = []
    k = 0

    def step(label: str) -> None:
        nonlocal k
        k += 1
        print(f"[{k}/{steps}] {label} ...", file=sys.stderr, flush=True)

    step("quasi-static test (4 mm/s, ±75 mm, 150 s)")
    results["quasi_static"] = runner.run_quasi_static(model, out, progress=say_wrote)
    step(f"chirp 0.5–16 Hz, {args.duration:g} s")
    results["chirp"] = runner.run_chirp(model, out, duration=args.duration,
                                        progress=say_wrote)
    sines = []
    for freq, amp in PAPER_SINES:
        step(f"sine {freq:g} Hz, {amp * 1e3:g} mm")
        s = runner.run_sine(model, out, freq, amp, progress=say_wrote)
        results[f"sine_{freq:g}hz"] = s
        data = read_measured_csv(out / s["files"][0])  # the file, as a user would read it
        sines.append((f"{freq:g} Hz, ±{amp * 1e3:g} mm "
                      f"({s['energy_per_cycle_j']:.0f} J/cycle)",
                      data.displacement, data.velocity, data.force))
    step("overlay of the paper's sines")
    overlay = plots.plot_sines_overlay(
        out / "paper_sines.png", sines, cfg=model.cfg,
        title=f"Paper's validation sines ({model.cfg.damper.name} damper, compressible "
              "model): hysteresis grows with frequency")
    say_wrote(overlay)
    step("14-speed test (0.025 m amplitude, 0.025–1.5 m/s)")
    results["14speed"] = runner.run_fourteen_speed(model, out, progress=say_wrote)
    for r in results.values():
        files += r["files"]
    files += [overlay.name, "demo.json"]
    elapsed = time.perf_counter() - started
    write_json(out / "demo.json", {
        "mode": "virtual-dyno",
        "note": "the closed-loop ROS 2 demo replaces this virtual-dyno demo later",
        "params_file": params_file,
        "damper": model.cfg.damper.name,
        "chirp_duration_s": args.duration,
        "files": files,
        "results": results,
        "elapsed_s": round(elapsed, 3),
    })
    print(f"demo finished in {elapsed:.1f} s; results in {out}", file=sys.stderr)
    return 0
