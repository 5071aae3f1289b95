"""``damper-hil skyhook``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from can_bridge.settings import BridgeParams
from damper_hil.cli.common import PROG, CliError, Formatter, load_model, positive_float, write_json


def add_parser(sub) -> None:
    sky = sub.add_parser(
        "skyhook", formatter_class=Formatter,
        help="run the reference skyhook controller on the CAN bus (VEHICLE_MOTION in, "
             "VALVE_COMMAND out)",
        description="Run the continuous semi-active skyhook controller (ride_sim/skyhook.py)\n"
                    "as an adaptive-damper ECU would: on the CAN bus only, no ROS.  It\n"
                    "reads VEHICLE_MOTION frames (from a bridge in controller mode) and sends\n"
                    "VALVE_COMMAND frames at skyhook.rate_hz until SIGINT/SIGTERM or\n"
                    "--duration; while VEHICLE_MOTION is silent it sends nothing (the bridge\n"
                    "then applies its fail-safe command).",
        epilog="example:\n"
               f"  {PROG} skyhook --can-interface udp_multicast --can-channel "
               "'[ff11::d4:1]:43000'")
    sky.add_argument("--params", metavar="FILE", type=Path, default=None,
                     help="skyhook params file (default: config/skyhook.yaml)")
    sky.add_argument("--damper-params", metavar="FILE", type=Path, default=None,
                     help="damper whose comfort/sport rates the law uses (rates_from: model; "
                          "default: config/sport.yaml)")
    sky.add_argument("--can-interface", metavar="NAME", default=BridgeParams.can_interface,
                     help=f"python-can interface (default: the bridge's, "
                          f"{BridgeParams.can_interface})")
    sky.add_argument("--can-channel", metavar="CHANNEL", default=BridgeParams.can_channel,
                     help=f"channel (default: the bridge's, {BridgeParams.can_channel})")
    sky.add_argument("--duration", metavar="S", type=positive_float, default=None,
                     help="stop after S seconds (default: until SIGINT/SIGTERM)")
    sky.add_argument("--json", metavar="FILE", type=Path, default=None,
                     help="write the controller's statistics here at the end")
    sky.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    import signal
    import threading

    from can_bridge.bus import BusConfig, CanBusError, open_bus
    from can_bridge.dbc import load_database
    from can_bridge.skyhook_controller import run_skyhook
    from ride_sim.skyhook import load_skyhook, resolve_rates

    params = load_skyhook(args.params)
    model = load_model(args.damper_params)[0] if params.rates_from == "model" \
        else None
    rates = resolve_rates(params, model)
    try:
        bus = BusConfig(interface=args.can_interface, channel=args.can_channel)
        open_bus(bus).shutdown()
    except (ValueError, CanBusError) as exc:
        raise CliError(str(exc)) from None
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.duration:
        threading.Timer(args.duration, stop.set).start()

    def log(text: str) -> None:
        print(f"[skyhook] {text}", file=sys.stderr, flush=True)

    log(f"on {bus.interface} {bus.channel}: c_sky {params.c_sky_ns_m:g} N s/m at "
        f"{params.rate_hz:g} Hz; rates soft/firm rebound {rates.soft_rebound:.0f}/"
        f"{rates.firm_rebound:.0f}, compression {rates.soft_compression:.0f}/"
        f"{rates.firm_compression:.0f} N s/m")
    stats = run_skyhook(bus, load_database(), params, rates, stop, log=log)
    log(f"stopped: {stats.motion_frames} VEHICLE_MOTION frames in, {stats.commands_sent} "
        f"VALVE_COMMAND frames out")
    if args.json:
        write_json(args.json, stats.as_dict())
    return 0
