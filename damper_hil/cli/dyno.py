"""``damper-hil dyno``."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from damper_emulator.dyno.formats import DEFAULT_FORMAT, FORMAT_HELP, FORMATS
from damper_emulator.dyno.protocols import PROTOCOLS
from damper_emulator.schema import field_spec
from damper_hil.cli.common import (
    PROG,
    CliError,
    Formatter,
    load_model,
    non_negative_float,
    non_negative_int,
    say_wrote,
    schema_type,
    write_json,
)
from damper_hil.cli.virtual_rig import add_can_log_option

#: unit suffixes of the schema's field names, left out of the option names
_UNIT_SUFFIXES = ("_m_s", "_hz", "_s", "_m")


def option_dest(name: str) -> str:
    """The option (its ``dest``) of a protocol schema field: the name without its unit,
    ``f_start_hz`` → ``f_start`` (``--f-start``)."""
    for suffix in _UNIT_SUFFIXES:
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


#: protocol → {option dest: default}, from the protocols' schemas; an option that is not
#: listed does not apply
PROTOCOL_DEFAULTS: dict[str, dict[str, Any]] = {
    name: {option_dest(f.name): f.default for f in dataclasses.fields(cls)}
    for name, cls in PROTOCOLS.items()}
#: option dest → [(protocol, its schema field)], in order of first appearance
_PROTOCOL_OPTIONS: dict[str, list[tuple[str, dataclasses.Field]]] = {}
for _name, _cls in PROTOCOLS.items():
    for _f in dataclasses.fields(_cls):
        _PROTOCOL_OPTIONS.setdefault(option_dest(_f.name), []).append((_name, _f))


def _add_protocol_options(group) -> None:
    """One option per protocol setting: its type and rule, description, unit and the
    default of each protocol it applies to, all from the schema."""
    for dest, users in _PROTOCOL_OPTIONS.items():
        option = "--" + dest.replace("_", "-")
        first = users[0][1]
        spec = field_spec(first, option)
        where = "" if len(users) == len(PROTOCOLS) else "".join(f"[{n}] " for n, _ in users)
        defaults = (", ".join(f"{n} {f.default:g}" for n, f in users)
                    if len({f.default for _, f in users}) > 1 else f"{first.default:g}")
        group.add_argument(option, dest=dest, metavar=(spec.unit or "N").upper(),
                           type=schema_type(first, option),
                           help=f"{where}{spec.description} (default: {defaults})")


def add_parser(sub) -> None:
    dyno = sub.add_parser(
        "dyno", formatter_class=Formatter,
        help="virtual dyno: run a test protocol on the model, write CSV + plots",
        description="Run a dyno test protocol on the compressible (hysteretic) damper model\n"
                    "and write into --out DIR: the measured data (time [s], displacement\n"
                    "[m, extension +], velocity [m/s], force [N, rebound +]; CSV, MDF4 with\n"
                    "--format mf4, or both), its\n"
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
    dyno.add_argument("--format", dest="fmt", choices=list(FORMATS), default=DEFAULT_FORMAT,
                      help=FORMAT_HELP + "; the 14-speed table is CSV")
    dyno.add_argument("--no-plot", dest="plot", action="store_false",
                      help="write the CSV and dyno.json only, no PNG (faster: plotting is "
                      "most of a short run's time)")
    _add_protocol_options(dyno.add_argument_group("protocol options (default: per protocol)"))
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
    r = dyno.add_argument_group(
        "a physical damper on a CAN dyno (--can-interface without --over-can)")
    r.add_argument("--rig-config", metavar="HYBRID.yaml", type=Path, default=None,
                   help="the run's settle, identification, compensation and safety limits "
                        "(groups hybrid, compensator, safety; default: config/hybrid.yaml). "
                        "The protocol runs on the dyno through DYNO_COMMAND/DYNO_FEEDBACK "
                        "(docs/hybrid.md), compensated for its delay and servo; the CSVs "
                        "record the stroke and force it measured; exit status 3 when the "
                        "safety layer stops it")
    add_can_log_option(r)
    dyno.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    opts = _protocol_options(args)  # before the heavy imports: a typo fails fast
    model, params_file = load_model(args.params)
    if args.over_can:
        if args.rig_config is not None:
            raise CliError("--rig-config is for a physical dyno, not with --over-can")
        return _dyno_over_can(args, opts, model, params_file)
    if args.can_interface is not None or args.can_channel is not None:
        return _dyno_on_rig(args, opts, model, params_file)
    if args.can_log is not None:
        raise CliError("--can-log is for a physical dyno (--can-interface without "
                       "--over-can)")
    if args.rig_config is not None:
        raise CliError("--rig-config needs --can-interface and --can-channel (the dyno's "
                       "bus)")
    return _run_dyno(args, opts, model, params_file)


def _dyno_on_rig(args: argparse.Namespace, opts: dict, model, params_file) -> int:
    from can_bridge.dbc import HYBRID_SIGNALS, load_database
    from can_bridge.dyno_rig import RigEngine, RigStopped
    from damper_emulator.realtime.rt import RealtimeRequest
    from damper_hil.cli.virtual_rig import can_log_of, open_checked_bus
    from ride_sim.hybrid.params import load_hybrid_config

    if args.noise_std:
        raise CliError("--noise-std does not apply on a dyno (the forces are measured)")
    if args.can_interface is None or args.can_channel is None:
        raise CliError("a physical dyno needs both --can-interface and --can-channel")
    if args.external:
        raise CliError("--external is for --over-can")
    config = load_hybrid_config(args.rig_config)
    db = load_database(required=HYBRID_SIGNALS)
    bus = open_checked_bus(args)
    try:
        with can_log_of(args) as can_log:
            engine = RigEngine(bus, db, config, realtime=RealtimeRequest(priority=70),
                               progress=lambda phase: print(f"dyno on the rig: {phase}",
                                                            file=sys.stderr, flush=True),
                               can_log=can_log)
            try:
                status = _run_dyno(args, opts, model, params_file, engine=engine,
                                   extra={"rig": {"interface": bus.interface,
                                                  "channel": bus.channel,
                                                  "runs": engine.runs}})
            finally:
                engine.close()
    except RigStopped as exc:
        write_json(args.out / "dyno.json", {"protocol": args.protocol, "status": "stopped",
                                            "reason": str(exc),
                                            "rig": {"runs": engine.runs}})
        print(f"{PROG}: stopped: {exc}", file=sys.stderr)
        return 3
    return status
def _protocol_options(args: argparse.Namespace) -> dict[str, Any]:
    """The options of ``args.protocol``, defaults filled in; an option given for another
    protocol is an error."""
    defaults = PROTOCOL_DEFAULTS[args.protocol]
    for dest, users in _PROTOCOL_OPTIONS.items():
        if dest not in defaults and getattr(args, dest) is not None:
            users = [p for p, _ in users]
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

    common = dict(noise_std=args.noise_std, seed=args.seed, progress=say_wrote, engine=engine,
                  plot=args.plot)
    out: Path = args.out
    if args.protocol == "sine":
        summary = runner.run_sine(model, out, opts["frequency"], opts["amplitude"],
                                  opts["cycles"], opts["rate"], opts["settle_cycles"],
                                  fmt=args.fmt, **common)
    elif args.protocol == "quasi-static":
        summary = runner.run_quasi_static(model, out, opts["velocity"], opts["amplitude"],
                                          opts["cycles"], opts["rate"], fmt=args.fmt,
                                          **common)
    elif args.protocol == "chirp":
        summary = runner.run_chirp(model, out, opts["f_start"], opts["f_end"],
                                   opts["duration"], opts["v_start"], opts["v_end"],
                                   opts["rate"], fmt=args.fmt, **common)
    else:
        summary = runner.run_fourteen_speed(model, out, opts["points"], opts["amplitude"],
                                            opts["v_min"], opts["v_max"], opts["cycles"],
                                            opts["rate"], **common)
    write_json(out / "dyno.json", {
        "protocol": args.protocol,
        "options": {**opts, "noise_std_n": args.noise_std, "seed": args.seed,
                    "format": args.fmt},
        "params_file": params_file,
        "damper": model.cfg.damper.name,
        "files": summary["files"] + ["dyno.json"],
        "summary": summary,
        **(extra or {}),
    })
    return 0
