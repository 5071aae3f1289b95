"""``damper-hil hybrid``."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from damper_emulator.dyno.formats import DEFAULT_FORMAT, FORMAT_HELP, FORMATS
from damper_hil.cli.common import (
    PROG,
    CliError,
    Formatter,
    add_realtime_options,
    say,
    say_wrote,
    schema_type,
    write_json,
)
from damper_hil.cli.virtual_rig import (
    add_bus_options,
    add_can_log_option,
    can_log_of,
    open_checked_bus,
)
from ride_sim.hybrid.params import COMPENSATION_MODES, ROAD_CLASSES, HybridRunParams

if TYPE_CHECKING:
    from ride_sim.hybrid.learn import LearnedTwin

#: Exit status of a run the safety layer stopped.
EXIT_STOPPED = 3


def add_parser(sub) -> None:
    hy = sub.add_parser(
        "hybrid", formatter_class=Formatter,
        help="a physical damper in the loop: the quarter car drives a dyno over CAN, "
             "compensated, safe, with the model beside it as a twin",
        description="Ride the quarter car in real time with a physical damper on a CAN dyno\n"
                    "(or `damper-hil virtual-rig`): each cycle the car's damper stroke goes\n"
                    "out as DYNO_COMMAND, compensated for the rig's delay and servo, and the\n"
                    "force measured in DYNO_FEEDBACK drives the car.  The run holds the\n"
                    "static position, identifies the rig's transfer system with a short\n"
                    "low-amplitude signal, ramps the road in, rides, ramps out and returns.\n"
                    "The safety layer clamps every demand into the limits, clears Enable\n"
                    "within 50 ms of the last valid feedback and stops a loop going\n"
                    "unstable.  Writes into --out DIR: hybrid.csv, hybrid.json, bag/ (rosbag2,\n"
                    "MCAP), ride_measured.csv (--format: or .mf4, with hybrid.mf4),\n"
                    "report.md and its plots.  Exit status 0 completed, 3 stopped by\n"
                    "the safety layer (the reason on stderr), 2 bad input or no dyno.",
        epilog="examples (two shells):\n"
               f"  {PROG} virtual-rig --can-interface udp_multicast "
               "--can-channel '[ff11::d5:1]:43210'\n"
               f"  {PROG} hybrid --out hybrid_out --duration 20 --can-interface "
               "udp_multicast --can-channel '[ff11::d5:1]:43210'\n"
               "with a real dyno on can0 (it must speak DYNO_COMMAND/DYNO_FEEDBACK of\n"
               "config/damper.dbc):\n"
               f"  {PROG} hybrid --out first_ride --duration 5 --road-class A "
               "--can-interface socketcan --can-channel can0")
    hy.add_argument("--out", metavar="DIR", type=Path, required=True,
                    help="output directory (created; must not hold an earlier run's bag)")
    # the options of the run's schema (ride_sim.hybrid.params.HybridRunParams)
    defaults = HybridRunParams()
    fields = {f.name: f for f in dataclasses.fields(HybridRunParams)}
    hy.add_argument("--duration", metavar="S", type=schema_type(fields["duration_s"],
                                                                "--duration"),
                    default=None, help=f"evaluated ride [s] (default: {defaults.duration_s:g})")
    hy.add_argument("--road-class", choices=ROAD_CLASSES, default=None,
                    help=f"ISO 8608 road class (default: {defaults.road_class})")
    hy.add_argument("--speed", metavar="M/S", type=schema_type(fields["speed_m_s"],
                                                               "--speed"),
                    default=None, help=f"vehicle speed [m/s] (default: {defaults.speed_m_s:g})")
    hy.add_argument("--seed", metavar="N", type=schema_type(fields["seed"], "--seed"),
                    default=None, help=f"random-road seed (default: {defaults.seed})")
    hy.add_argument("--twin", metavar="PARAMS.yaml", type=Path, default=None,
                    help="the damper's model: the twin, the compensator's prediction and the "
                         "reference (default: config/sport.yaml)")
    hy.add_argument("--learn", action="store_true",
                    help="before the ride, the twin learns the specimen: a quasi-static test "
                         "and a chirp on the rig (the config's group learn), identified into "
                         "the twin; written to DIR/learn/ (twin_learned.yaml), and the ride "
                         "runs with it")
    hy.add_argument("--compensation", choices=COMPENSATION_MODES, default=None,
                    help="model: compensate the rig's delay and servo (default); none: send "
                         "the car's stroke as it is")
    hy.add_argument("--config", metavar="FILE", type=Path, default=None,
                    help="hybrid parameter file: groups hybrid, safety, compensator "
                         "(default: config/hybrid.yaml)")
    hy.add_argument("--quarter-car", metavar="FILE", type=Path, default=None,
                    help="quarter-car parameter file (default: config/quarter_car.yaml)")
    add_bus_options(hy)
    add_can_log_option(hy)
    hy.add_argument("--json", metavar="FILE", type=Path, default=None,
                    help="also write hybrid.json's content to FILE")
    hy.add_argument("--no-bag", action="store_true", help="do not record the bag")
    hy.add_argument("--format", dest="fmt", choices=list(FORMATS), default=DEFAULT_FORMAT,
                    help=FORMAT_HELP + ": ride_measured.csv/.mf4, and hybrid.mf4 beside "
                         "hybrid.csv (the live record, always written)")
    hy.add_argument("--ros", action="store_true",
                    help="publish the twin's residual, the tracking and the rig's delay on "
                         "/diagnostics once a second (node damper_hil_hybrid; ROS_DOMAIN_ID "
                         "from the environment)")
    add_realtime_options(hy, 70)
    hy.set_defaults(handler=run)


def _finite(doc: Any) -> Any:
    """``doc`` with non-finite numbers as null (JSON has none)."""
    if isinstance(doc, dict):
        return {k: _finite(v) for k, v in doc.items()}
    if isinstance(doc, (list, tuple)):
        return [_finite(v) for v in doc]
    if isinstance(doc, float) and not math.isfinite(doc):
        return None
    return doc


def _learn(out: Path, twin: Any, config: Any, bus: Any, db: Any, realtime: Any
           ) -> LearnedTwin | int:
    """The twin learns the specimen (:func:`ride_sim.hybrid.learn.learn_twin`) on the rig
    of ``bus``: the :class:`~ride_sim.hybrid.learn.LearnedTwin`, or the exit status of a
    characterisation the safety layer stopped (``hybrid.json`` says why)."""
    from can_bridge.dyno_rig import RigEngine, RigStopped
    from ride_sim.hybrid.learn import learn_twin

    engine = RigEngine(bus, db, config, realtime=realtime,
                       progress=lambda phase: say(f"hybrid: learn on the rig: {phase}"))
    try:
        return learn_twin(twin, config.learn, out / "learn", engine, progress=say)
    except RigStopped as exc:
        write_json(out / "hybrid.json", {"status": "stopped", "reason": str(exc),
                                         "phase_at_end": "learn",
                                         "twin_learning": {"runs": engine.runs}})
        print(f"{PROG}: stopped: {exc}", file=sys.stderr)
        return EXIT_STOPPED
    finally:
        engine.close()


def run(args: argparse.Namespace) -> int:
    import signal
    import threading
    import time

    from can_bridge.dbc import HYBRID_SIGNALS, load_database
    from can_bridge.hybrid_link import dyno_answers, run_hybrid_link
    from damper_emulator.params import DEFAULT_PARAMS_FILE
    from damper_emulator.realtime.rt import RealtimeRequest
    from damper_hil.cli.common import load_model
    from damper_hil.hybrid_report import write_report
    from ride_sim.hybrid.criteria import summary
    from ride_sim.hybrid.host import HybridHost, export_measured
    from ride_sim.hybrid.learn import LearnedTwin
    from ride_sim.hybrid.params import load_hybrid_config
    from ride_sim.hybrid.recorder import HybridRecorder, WriterProcess
    from ride_sim.hybrid.rig_host import HOST_CYCLE_S, export_record_mdf, fit_worker
    from ride_sim.params import load_quarter_car

    config = load_hybrid_config(args.config)
    changes = {name: value for name, value in (
        ("duration_s", args.duration), ("road_class", args.road_class),
        ("speed_m_s", args.speed), ("seed", args.seed)) if value is not None}
    run_params = dataclasses.replace(config.hybrid, **changes)
    compensator = config.compensator if args.compensation is None else \
        dataclasses.replace(config.compensator, mode=args.compensation)
    if args.learn:
        from ride_sim.hybrid.learn import check_safe

        check_safe(config.learn, config.safety)
    car = load_quarter_car(args.quarter_car)
    twin, twin_file = load_model(args.twin)
    db = load_database(required=HYBRID_SIGNALS)
    bus = open_checked_bus(args)
    out: Path = args.out
    if (out / "bag").exists():
        raise CliError(f"{out / 'bag'} exists: give a new --out directory (a run never "
                       "overwrites a recording)")
    wait_s = config.hybrid.connect_timeout_s
    if not dyno_answers(bus, db, wait_s):           # before the host's seconds of building
        raise CliError(f"no DYNO_FEEDBACK within {wait_s:g} s on {bus.interface} "
                       f"{bus.channel} (is a dyno on the bus?)")
    out.mkdir(parents=True, exist_ok=True)
    realtime = RealtimeRequest(priority=args.priority, cpu=args.cpu)
    learned = None
    if args.learn:
        learned = _learn(out, twin, config, bus, db, realtime)
        if not isinstance(learned, LearnedTwin):
            return learned
        twin, twin_file = learned.model, str(learned.params_file)

    say(f"hybrid: {run_params.duration_s:g} s of an ISO 8608 class {run_params.road_class} "
        f"road at {run_params.speed_m_s:g} m/s, {compensator.mode} compensation, twin "
        f"{twin_file}, on {bus.interface} {bus.channel}")
    # the fit's worker and the record's writer start up (imports, the bag) while the
    # host builds and warms up
    executor = fit_worker("hybrid-fit")
    writer = WriterProcess(out, HOST_CYCLE_S, bag=not args.no_bag)
    status = None
    # until the recorder takes the writer over, a failure (a host that cannot be built, a
    # ROS node that cannot start) must end it too: its pipe held open would keep the
    # writer, and so this process, waiting
    try:
        host = HybridHost(run_params, car, twin, compensator, config.safety,
                          dt_s=HOST_CYCLE_S, executor=executor, learn=config.learn)
        host.warm_up()
        stop = threading.Event()
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())

        def progress(phase: str) -> None:
            if phase == "rearm" and host.restarts:      # why, and how many are left
                last = host.restarts[-1]
                say(f"hybrid: stopped in {last['phase']} ({last['reason']}); starting "
                    f"again, restart {len(host.restarts)} of {run_params.restarts}")
            else:
                say(f"hybrid: {phase}")

        if args.ros:
            from damper_emulator.ros.status_publisher import StatusPublisher
            from ride_sim.hybrid.recorder import DIAGNOSTIC_NAME, JOINT

            status = StatusPublisher("damper_hil_hybrid")

        def on_status(level: int, message: str, values: list[tuple[str, str]]) -> None:
            if status is not None:
                status.publish(DIAGNOSTIC_NAME, level, message, JOINT, dict(values))

        started = time.monotonic()
        with HybridRecorder(out, host, bag=not args.no_bag, writer=writer,
                            on_status=on_status if status is not None else None) as recorder, \
                can_log_of(args) as can_log:
            stats = run_hybrid_link(bus, db, host, stop, realtime=realtime,
                                    progress=progress, can_log=can_log)
        if recorder.error is not None:
            raise recorder.error
    finally:
        writer.close()          # idempotent: the recorder has closed it when it ran
        executor.close()
        if status is not None:
            status.close()
    doc = summary(host)
    doc["link"] = stats.summary()
    doc["elapsed_s"] = time.monotonic() - started
    if learned is not None:
        doc["twin_learning"] = learned.to_json()
    doc["settings"] = {"hybrid": dataclasses.asdict(run_params),
                       "compensator": dataclasses.asdict(compensator),
                       "safety": dataclasses.asdict(config.safety),
                       "twin": twin_file, "default_twin": str(DEFAULT_PARAMS_FILE),
                       "bus": f"{bus.interface}:{bus.channel}"}
    doc = _finite(doc)
    write_json(out / "hybrid.json", doc)
    if args.json:
        write_json(args.json, doc)
    say_wrote(out / "hybrid.csv")
    if ".mf4" in FORMATS[args.fmt]:
        say_wrote(export_record_mdf(host, out / "hybrid.mf4"))
    for measured in export_measured(host, out / "ride_measured.csv", args.fmt):
        say_wrote(measured)
    if not args.no_bag:
        say_wrote(out / "bag")
    if host.transfer is not None or host.k > 0:
        for path in write_report(out, host, doc):
            say_wrote(path)
    if host.failure is not None and host.transfer is None and host.k == 0 \
            and host.safety.reason is None:
        raise CliError(host.failure)
    if doc["status"] != "completed":
        print(f"{PROG}: stopped: {doc['reason']}", file=sys.stderr)
        return EXIT_STOPPED
    tr = doc["tracking"]
    say(f"hybrid: completed; tracking NRMS {tr['nrms']:.2%}, residual delay "
        f"{tr['delay_ms']:.2f} ms; twin residual {doc['twin']['residual_rms_n']:.1f} N r.m.s.")
    return 0
