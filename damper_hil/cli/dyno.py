"""``damper-hil dyno``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from damper_hil.cli.common import (
    PROG,
    CliError,
    Formatter,
    load_model,
    non_negative_float,
    non_negative_int,
    point_count,
    positive_float,
    positive_int,
    say_wrote,
    write_json,
)

#: protocol → {option dest: default}; an option that is not listed does not apply
PROTOCOL_DEFAULTS: dict[str, dict[str, Any]] = {
    "sine": {"frequency": 1.0, "amplitude": 0.05, "cycles": 3, "rate": 1000.0,
             "settle_cycles": 1},
    "quasi-static": {"velocity": 0.004, "amplitude": 0.075, "cycles": 2, "rate": 50.0},
    "chirp": {"f_start": 0.5, "f_end": 16.0, "duration": 60.0, "v_start": 0.05,
              "v_end": 1.5, "rate": 1000.0},
    "14-speed": {"points": 14, "amplitude": 0.025, "v_min": 0.025, "v_max": 1.5,
                 "cycles": 2, "rate": 1000.0},
}
_PROTOCOL_OPTIONS = sorted({k for d in PROTOCOL_DEFAULTS.values() for k in d})


def add_parser(sub) -> None:
    dyno = sub.add_parser(
        "dyno", formatter_class=Formatter,
        help="virtual dyno: run a test protocol on the model, write CSV + plots",
        description="Run a dyno test protocol on the compressible (hysteretic) damper model\n"
                    "and write into --out DIR: the measured-data CSV (time [s], displacement\n"
                    "[m, extension +], velocity [m/s], force [N, rebound +]), its\n"
                    "force–velocity / force–displacement plot (PNG) and dyno.json\n"
                    "(protocol, options, parameter file, files written, summary).",
        epilog="files written per protocol:\n"
               "  sine          sine_<f>hz.csv, sine_<f>hz.png   (<f> = frequency, %g)\n"
               "  quasi-static  quasi_static.csv, quasi_static.png\n"
               "  chirp         chirp.csv, chirp.png\n"
               "  14-speed      14speed.csv (frequency_hz, peak_velocity_rebound_m_s,\n"
               "                peak_force_rebound_n, peak_velocity_compression_m_s,\n"
               "                peak_force_compression_n), 14speed.png\n"
               "Options marked [sine], [chirp], ... apply to those protocols only; their\n"
               "defaults are per protocol.\n"
               "examples:\n"
               f"  {PROG} dyno --protocol sine --frequency 3 --amplitude 0.05 --out dyno_out\n"
               f"  {PROG} dyno --protocol chirp --duration 30 --noise-std 5 --out dyno_out")
    dyno.add_argument("--protocol", required=True, choices=list(PROTOCOL_DEFAULTS),
                      help="test protocol: quasi-static (4 mm/s triangle), chirp (swept sine), "
                           "sine, 14-speed (peak force vs peak velocity)")
    dyno.add_argument("--params", metavar="PARAMS.yaml", type=Path, default=None,
                      help="damper parameter file (ROS 2 params YAML; default: "
                           "config/sport.yaml)")
    dyno.add_argument("--out", metavar="DIR", type=Path, required=True,
                      help="output directory (created if missing)")
    dyno.add_argument("--noise-std", metavar="N", type=non_negative_float, default=0.0,
                      help="standard deviation of Gaussian noise added to the force [N] "
                           "(default: 0, no noise)")
    dyno.add_argument("--seed", metavar="S", type=non_negative_int, default=0,
                      help="seed of the force-noise generator (default: 0)")
    g = dyno.add_argument_group("protocol options (default: per protocol)")
    g.add_argument("--frequency", metavar="HZ", type=positive_float,
                   help="[sine] frequency [Hz] (default: 1)")
    g.add_argument("--amplitude", metavar="M", type=positive_float,
                   help="displacement amplitude [m]: [sine] 0.05, [quasi-static] 0.075, "
                        "[14-speed] 0.025")
    g.add_argument("--cycles", metavar="N", type=positive_int,
                   help="recorded cycles: [sine] 3, [quasi-static] 2, [14-speed] 2 per "
                        "frequency")
    g.add_argument("--settle-cycles", metavar="N", type=non_negative_int,
                   help="[sine] lead-in cycles simulated but not recorded (default: 1)")
    g.add_argument("--rate", metavar="HZ", type=positive_float,
                   help="sample rate [Hz]: [quasi-static] 50, others 1000")
    g.add_argument("--velocity", metavar="M/S", type=positive_float,
                   help="[quasi-static] constant stroke velocity [m/s] (default: 0.004)")
    g.add_argument("--f-start", metavar="HZ", type=positive_float,
                   help="[chirp] start frequency [Hz] (default: 0.5)")
    g.add_argument("--f-end", metavar="HZ", type=positive_float,
                   help="[chirp] end frequency [Hz] (default: 16)")
    g.add_argument("--duration", metavar="S", type=positive_float,
                   help="[chirp] sweep duration [s] (default: 60)")
    g.add_argument("--v-start", metavar="M/S", type=positive_float,
                   help="[chirp] velocity amplitude at the start [m/s] (default: 0.05)")
    g.add_argument("--v-end", metavar="M/S", type=positive_float,
                   help="[chirp] velocity amplitude at the end [m/s] (default: 1.5)")
    g.add_argument("--points", metavar="N", type=point_count,
                   help="[14-speed] number of test speeds (default: 14)")
    g.add_argument("--v-min", metavar="M/S", type=positive_float,
                   help="[14-speed] lowest peak velocity [m/s] (default: 0.025)")
    g.add_argument("--v-max", metavar="M/S", type=positive_float,
                   help="[14-speed] highest peak velocity [m/s] (default: 1.5)")
    c = dyno.add_argument_group(
        "loopback dyno over CAN (the protocol in real time against emulator + bridge)")
    c.add_argument("--over-can", action="store_true",
                   help="send the samples as DAMPER_STATE frames at the protocol's rate and "
                        "take the forces from DAMPER_FORCE frames; starts the emulator "
                        "(trigger: input) and the bridge (mode dyno) unless --external; "
                        "dyno.json gets the comparison with the offline model")
    c.add_argument("--can-interface", metavar="NAME", default=None,
                   help="python-can interface (default: socketcan where the kernel has it, "
                        "else udp_multicast)")
    c.add_argument("--can-channel", metavar="CHANNEL", default=None,
                   help="channel (default: vcan0 for socketcan; for udp_multicast a group "
                        "and port private to this run, e.g. [ff11::d4:1]:43000)")
    c.add_argument("--external", action="store_true",
                   help="the emulator (emulator.trigger: input) and a bridge in dyno mode "
                        "already run on the bus: start nothing")
    dyno.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    opts = _protocol_options(args)  # before the heavy imports: a typo fails fast
    model, params_file = load_model(args.params)
    if args.over_can:
        return _dyno_over_can(args, opts, model, params_file)
    return _run_dyno(args, opts, model, params_file)
def _protocol_options(args: argparse.Namespace) -> dict[str, Any]:
    """The options of ``args.protocol``, defaults filled in; an option given for another
    protocol is an error."""
    defaults = PROTOCOL_DEFAULTS[args.protocol]
    for dest in _PROTOCOL_OPTIONS:
        if dest not in defaults and getattr(args, dest) is not None:
            users = [p for p, d in PROTOCOL_DEFAULTS.items() if dest in d]
            raise CliError(f"--{dest.replace('_', '-')} does not apply to --protocol "
                           f"{args.protocol} (only to {', '.join(users)})")
    return {dest: (getattr(args, dest) if getattr(args, dest) is not None else default)
            for dest, default in defaults.items()}
def _dyno_over_can(args: argparse.Namespace, opts: dict, model, params_file) -> int:
    from can_bridge.dyno_client import OverCanError
    from can_bridge.loopback import Loopback, default_bus

    try:
        bus = default_bus(args.can_interface, args.can_channel)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if args.noise_std:
        raise CliError("--noise-std does not apply with --over-can (the forces are measured)")
    lb = Loopback(bus, args.out, Path(params_file) if args.params else None,
                  start_nodes=not args.external,
                  progress=lambda text: print(text, file=sys.stderr, flush=True))
    try:
        with lb:
            status = _run_dyno(args, opts, model, params_file, engine=lb.engine,
                               extra={"over_can": {"interface": bus.interface,
                                                   "channel": bus.channel,
                                                   "nodes_started": not args.external,
                                                   "runs": lb.comparisons}})
    except OverCanError as exc:
        raise CliError(str(exc)) from None
    worst = max(r["relative_rms_vs_offline_quantised"] for r in lb.comparisons)
    p99 = max(r["round_trip_p99_ms"] or 0.0 for r in lb.comparisons)
    print(f"over CAN: {len(lb.comparisons)} run(s), force r.m.s. difference from the offline "
          f"model ≤ {worst * 100:.3f} %, round trip p99 ≤ {p99:.2f} ms "
          f"(details in {args.out / 'dyno.json'})", file=sys.stderr)
    return status
def _run_dyno(args: argparse.Namespace, opts: dict, model, params_file, engine=None,
              extra: dict | None = None) -> int:
    from damper_emulator.dyno import runner

    common = dict(noise_std=args.noise_std, seed=args.seed, progress=say_wrote, engine=engine)
    out: Path = args.out
    if args.protocol == "sine":
        summary = runner.run_sine(model, out, opts["frequency"], opts["amplitude"],
                                  opts["cycles"], opts["rate"], opts["settle_cycles"],
                                  **common)
    elif args.protocol == "quasi-static":
        summary = runner.run_quasi_static(model, out, opts["velocity"], opts["amplitude"],
                                          opts["cycles"], opts["rate"], **common)
    elif args.protocol == "chirp":
        summary = runner.run_chirp(model, out, opts["f_start"], opts["f_end"],
                                   opts["duration"], opts["v_start"], opts["v_end"],
                                   opts["rate"], **common)
    else:
        summary = runner.run_fourteen_speed(model, out, opts["points"], opts["amplitude"],
                                            opts["v_min"], opts["v_max"], opts["cycles"],
                                            opts["rate"], **common)
    write_json(out / "dyno.json", {
        "protocol": args.protocol,
        "options": {**opts, "noise_std_n": args.noise_std, "seed": args.seed},
        "params_file": params_file,
        "damper": model.cfg.damper.name,
        "files": summary["files"] + ["dyno.json"],
        "summary": summary,
        **(extra or {}),
    })
    return 0
