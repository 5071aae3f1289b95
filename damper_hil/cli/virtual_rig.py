"""``damper-hil virtual-rig``."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from can_bridge.settings import BridgeParams
from damper_hil.cli.common import (
    PROG,
    CliError,
    Formatter,
    add_realtime_options,
    non_negative_float,
    non_negative_int,
    positive_float,
    say,
    write_json,
)

if TYPE_CHECKING:
    from can_bridge.can_log import CanLog


def add_bus_options(parser: argparse.ArgumentParser) -> None:
    """``--can-interface``, ``--can-channel``: the dyno's bus."""
    parser.add_argument("--can-interface", metavar="NAME", default=BridgeParams.can_interface,
                        help=f"python-can interface (default: {BridgeParams.can_interface}; "
                             "where the kernel has no SocketCAN: udp_multicast)")
    parser.add_argument("--can-channel", metavar="CHANNEL", default=BridgeParams.can_channel,
                        help=f"channel (default: {BridgeParams.can_channel}; udp_multicast: "
                             "an interface-local group and port, e.g. '[ff11::d5:1]:43210')")


def _can_log_path(text: str) -> Path:
    """A ``--can-log`` value: a new ``.blf`` or ``.asc`` file (checked as the options are
    read, before any work)."""
    from can_bridge.can_log import CanLogError, check_log_path

    try:
        return check_log_path(text)
    except CanLogError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_can_log_option(parser: argparse.ArgumentParser) -> None:
    """``--can-log FILE``: the process's CAN traffic as BLF or ASC."""
    parser.add_argument("--can-log", metavar="FILE.blf", type=_can_log_path, default=None,
                        help="also log every CAN frame this process sends and receives, "
                             "as Vector BLF (.blf) or ASC (.asc) by python-can's writers "
                             "(replay reads them back)")


@contextlib.contextmanager
def can_log_of(args: argparse.Namespace) -> Iterator[CanLog | None]:
    """The :class:`~can_bridge.can_log.CanLog` of ``--can-log`` (None: not asked for),
    closed when the block ends, with a line saying what it holds; a log that could not be
    written whole is one error line (unless the block failed: its error is the one told)."""
    from can_bridge.can_log import CanLog, CanLogError

    try:
        log = None if args.can_log is None else CanLog(args.can_log)
    except CanLogError as exc:
        raise CliError(str(exc)) from None
    def close() -> None:
        if log is not None:
            log.close()
            say(f"wrote {log.path} ({log.frames} CAN frames)")

    try:
        yield log
    except BaseException:
        with contextlib.suppress(CanLogError):    # the block's error is the one told
            close()
        raise
    try:
        close()
    except CanLogError as exc:
        raise CliError(str(exc)) from None


def open_checked_bus(args: argparse.Namespace):
    """The :class:`~can_bridge.bus.BusConfig` of the options, opened once now so that a
    bus that cannot be used is one line before any work."""
    from can_bridge.bus import BusConfig, CanBusError, open_bus

    try:
        bus = BusConfig(interface=args.can_interface, channel=args.can_channel)
        open_bus(bus).shutdown()
    except (ValueError, CanBusError) as exc:
        raise CliError(str(exc)) from None
    return bus


def add_parser(sub) -> None:
    rig = sub.add_parser(
        "virtual-rig", formatter_class=Formatter,
        help="play a damper dyno on the CAN bus for `damper-hil hybrid` (DYNO_COMMAND in, "
             "DYNO_FEEDBACK and DYNO_AUX out)",
        description="Play the dyno of a physical damper in the loop on the CAN bus: an\n"
                    "actuator with a transport delay and second-order servo dynamics, a\n"
                    "specimen damper (the model of --params, with any extension: e.g. a\n"
                    "thermal fade the host's twin lacks), load-cell and displacement noise.\n"
                    "It follows DYNO_COMMAND while Enable is set and commands keep coming,\n"
                    "and sends DYNO_FEEDBACK every cycle and DYNO_AUX (oil temperature)\n"
                    "every 100 ms, until SIGINT/SIGTERM or --duration.  Settings beyond the\n"
                    "options: the actuator and virtual_rig groups of --config (docs/hybrid.md).",
        epilog="examples:\n"
               f"  {PROG} virtual-rig --can-interface udp_multicast "
               "--can-channel '[ff11::d5:1]:43210'\n"
               f"  {PROG} virtual-rig --delay-ms 8 --bandwidth-hz 25 --params faded.yaml")
    rig.add_argument("--params", metavar="PARAMS.yaml", type=Path, default=None,
                     help="the specimen's parameter file (default: config/prototype.yaml, "
                          "a prototype of the sport damper that is not its model)")
    rig.add_argument("--config", metavar="FILE", type=Path, default=None,
                     help="hybrid parameter file, groups actuator and virtual_rig (default: "
                          "config/hybrid.yaml)")
    rig.add_argument("--delay-ms", metavar="MS", type=non_negative_float, default=None,
                     help="transport delay of the demand [ms] (default: the config's, 4)")
    rig.add_argument("--bandwidth-hz", metavar="HZ", type=positive_float, default=None,
                     help="servo natural frequency [Hz] (default: the config's, 40)")
    rig.add_argument("--damping", metavar="ZETA", type=positive_float, default=None,
                     help="servo damping ratio (default: the config's, 0.7)")
    add_bus_options(rig)
    add_can_log_option(rig)
    rig.add_argument("--duration", metavar="S", type=positive_float, default=None,
                     help="stop after S seconds (default: until SIGINT/SIGTERM)")
    rig.add_argument("--json", metavar="FILE", type=Path, default=None,
                     help="write the rig's statistics here at the end")
    f = rig.add_argument_group("fault injection (to test a host's safety layer)")
    f.add_argument("--delay-change-at", metavar="S", type=non_negative_float, default=None,
                   help="S seconds after the first valid command the delay becomes "
                        "--delay-change-to-ms")
    f.add_argument("--delay-change-to-ms", metavar="MS", type=non_negative_float,
                   default=None, help="the changed transport delay [ms]")
    f.add_argument("--corrupt-every", metavar="N", type=non_negative_int, default=0,
                   help="every N-th DYNO_FEEDBACK goes out with a wrong checksum")
    f.add_argument("--late-every", metavar="N", type=non_negative_int, default=0,
                   help="every N-th DYNO_FEEDBACK goes out a cycle late, just before the "
                        "next")
    f.add_argument("--feedback-stop-at", metavar="S", type=non_negative_float, default=None,
                   help="from S seconds after the first valid command no DYNO_FEEDBACK "
                        "goes out")
    add_realtime_options(rig, 75)
    rig.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import signal
    import sys
    import threading

    from can_bridge.dbc import HYBRID_SIGNALS, load_database
    from can_bridge.virtual_rig import RigFaults, run_virtual_rig
    from damper_emulator.model.compressible import DamperModel
    from damper_emulator.params import PROTOTYPE_FILE, load_config
    from damper_emulator.realtime.rt import RealtimeRequest
    from ride_sim.hybrid.params import load_hybrid_config
    from ride_sim.hybrid.rig import VirtualRig

    if (args.delay_change_at is None) != (args.delay_change_to_ms is None):
        raise CliError("--delay-change-at and --delay-change-to-ms go together")
    config = load_hybrid_config(args.config)
    changes = {k: v for k, v in (("delay_s", None if args.delay_ms is None
                                  else args.delay_ms * 1e-3),
                                 ("bandwidth_hz", args.bandwidth_hz),
                                 ("damping", args.damping)) if v is not None}
    actuator = dataclasses.replace(config.actuator, **changes)
    model = DamperModel(load_config(args.params if args.params is not None
                                    else PROTOTYPE_FILE))
    db = load_database(required=HYBRID_SIGNALS)
    bus = open_checked_bus(args)
    faults = RigFaults(
        delay_change_at_s=args.delay_change_at,
        delay_change_to_s=(args.delay_change_to_ms or 0.0) * 1e-3,
        corrupt_every=args.corrupt_every, late_every=args.late_every,
        feedback_stop_at_s=args.feedback_stop_at)
    rig = VirtualRig(model, actuator, config.virtual_rig)
    rig.specimen.warm_up()
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration:
        timer = threading.Timer(args.duration, stop.set)
        timer.daemon = True
        timer.start()

    def log(text: str) -> None:
        print(f"[virtual-rig] {text}", file=sys.stderr, flush=True)

    extensions = model.cfg.damper.extensions
    with_ext = f" with {', '.join(extensions.active())}" if extensions is not None else ""
    log(f"on {bus.interface} {bus.channel}: {model.cfg.damper.name} specimen{with_ext}"
        f"; delay {actuator.delay_s * 1e3:g} ms, servo {actuator.bandwidth_hz:g} Hz "
        f"damping {actuator.damping:g}; {config.virtual_rig.rate_hz:g} Hz")
    with can_log_of(args) as can_log:
        stats = run_virtual_rig(bus, db, rig, stop, faults=faults, log=log, can_log=can_log,
                                realtime=RealtimeRequest(priority=args.priority, cpu=args.cpu))
    say(f"[virtual-rig] stopped: {stats.cycles} cycles, {stats.commands} valid commands, "
        f"{stats.dropped} dropped, {stats.feedback_sent} feedback frames sent")
    if args.json:
        write_json(args.json, stats.as_dict())
    return 0
