"""``damper-hil demo``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from damper_hil.cli.common import CliError, Formatter, positive_float, positive_int
from ride_sim.params import CLOCKS, RideRunParams


def add_parser(sub) -> None:
    demo = sub.add_parser(
        "demo", formatter_class=Formatter,
        help="closed-loop HIL demo: emulator + ride simulation over ROS 2, recorded",
        description="Closed-loop hardware-in-the-loop demo on this machine.\n\n"
                    "Starts the damper_emulator node (1 kHz), the ride_sim node (quarter car\n"
                    "on the minor road at 20 m/s), the CAN bridge (controller mode), the\n"
                    "skyhook controller (a process on the CAN bus) and the recorder as\n"
                    "separate processes (localhost only, own ROS_DOMAIN_ID; CAN: socketcan\n"
                    "vcan0 where the kernel has it, else a private udp_multicast group), runs\n"
                    "DURATION seconds of road, and writes under DIR: bag/ (rosbag2, MCAP),\n"
                    "ride_metrics.json, skyhook.json, demo.json, report.md, ride.png,\n"
                    "damper.png, control.png, loop.png and logs/ (and demo.mf4 with\n"
                    "--format mf4).")
    demo.add_argument("--duration", metavar="S", type=positive_float,
                      default=RideRunParams.duration_s,
                      help=f"road time [s] (default: ride.duration_s, "
                           f"{RideRunParams.duration_s:g}; at least 5 at 20 m/s)")
    demo.add_argument("--clock", choices=CLOCKS, default=RideRunParams.clock,
                      help=f"ride clock (default: ride.clock, {RideRunParams.clock})")
    demo.add_argument("--control", choices=("skyhook", "passive"), default="skyhook",
                      help="skyhook: the reference skyhook controller commands the adaptive "
                           "damper over CAN; passive: the damper stays at sport (the bridge "
                           "still runs; default: skyhook)")
    demo.add_argument("--live", metavar="PORT", type=positive_int, nargs="?", const=8765,
                      default=None,
                      help="also serve the live view (damper-hil live) on ws://127.0.0.1:PORT "
                           "(default port 8765): open it in Foxglove or Lichtblick with "
                           "config/foxglove_layout.json")
    demo.add_argument("--format", dest="fmt", choices=("bag", "mf4"), default="bag",
                      help="the time series as the bag only (bag/, MCAP), or also as ASAM "
                           "MDF4 (demo.mf4: one channel group per topic, with units and "
                           "comments, for asammdf, CANape, INCA; default: bag)")
    demo.add_argument("--out", metavar="DIR", type=Path, default=Path("demo_out"),
                      help="output directory (created if missing; default: demo_out)")
    demo.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from damper_hil.hil_demo import DemoError, run_demo

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    try:
        summary = run_demo(args.out, args.duration, clock=args.clock, control=args.control,
                           live_port=args.live, mf4=args.fmt == "mf4", progress=progress)
    except DemoError as exc:
        raise CliError(str(exc)) from None
    m = summary["ride"]["metrics"]
    loop = summary["emulator_loop"] or {}
    print(f"demo finished in {summary['elapsed_s']:.0f} s: SWS r.m.s. {m['sws_rms'] * 1e3:.2f} "
          f"mm, Wk body acceleration r.m.s. {m['accel_w_rms']:.3f} m/s², DTL r.m.s. "
          f"{m['dtl_rms']:.0f} N; emulator loop p99 {loop.get('period_p99_us', float('nan')):.0f}"
          f" µs; bag and report in {args.out}", file=sys.stderr)
    return 0
