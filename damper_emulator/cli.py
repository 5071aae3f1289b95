"""The ``damper-hil`` command line (docs/interfaces.md §3).

Subcommands so far: ``dyno`` (virtual dyno), ``demo``, ``identify``, ``validate``,
``diagnose`` and ``ride-study``.  Every user error (bad parameter file, bad measured data, bad option value, an output that cannot be
written) is one line ``damper-hil: error: <message>`` on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

PROG = "damper-hil"

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

#: identify warns when a quasi-static file moves faster than this [m/s] (99th percentile):
#: twice the FSAE slow run's 26 mm/s, twelve times the paper's 4 mm/s
QUASI_STATIC_WARN_SPEED_M_S = 0.05
#: the paper's validation sines (docs/model.md §3): (frequency [Hz], amplitude [m])
PAPER_SINES = ((1.0, 0.05), (3.0, 0.05), (12.0, 0.005))


class CliError(Exception):
    """A user error detected by the command line itself (one-line message)."""


# --------------------------------------------------------------------------------------
# argument types


def _number(kind: str, test: Callable[[float], bool], cast: Callable = float):
    def parse(text: str):
        try:
            value = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}") from None
        if not (math.isfinite(value) and test(value)):
            raise argparse.ArgumentTypeError(f"expected {kind}, got {text!r}")
        return value
    return parse


_positive = _number("a positive number", lambda v: v > 0)
_non_negative = _number("a number >= 0", lambda v: v >= 0)
_pos_int = _number("a positive integer", lambda v: v >= 1, int)
_non_neg_int = _number("an integer >= 0", lambda v: v >= 0, int)
_points = _number("an integer >= 2", lambda v: v >= 2, int)


# --------------------------------------------------------------------------------------
# parser


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs keep their line breaks; option help is wrapped."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Hardware-in-the-loop damper emulator: Simms & Crolla hysteretic "
                    "mono-tube model, virtual dyno, identification and ride simulation.")
    from damper_emulator import __version__
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="SUBCOMMAND", required=True)

    # ---- dyno ------------------------------------------------------------------------
    dyno = sub.add_parser(
        "dyno", formatter_class=_Formatter,
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
    dyno.add_argument("--noise-std", metavar="N", type=_non_negative, default=0.0,
                      help="standard deviation of Gaussian noise added to the force [N] "
                           "(default: 0, no noise)")
    dyno.add_argument("--seed", metavar="S", type=_non_neg_int, default=0,
                      help="seed of the force-noise generator (default: 0)")
    g = dyno.add_argument_group("protocol options (default: per protocol)")
    g.add_argument("--frequency", metavar="HZ", type=_positive,
                   help="[sine] frequency [Hz] (default: 1)")
    g.add_argument("--amplitude", metavar="M", type=_positive,
                   help="displacement amplitude [m]: [sine] 0.05, [quasi-static] 0.075, "
                        "[14-speed] 0.025")
    g.add_argument("--cycles", metavar="N", type=_pos_int,
                   help="recorded cycles: [sine] 3, [quasi-static] 2, [14-speed] 2 per "
                        "frequency")
    g.add_argument("--settle-cycles", metavar="N", type=_non_neg_int,
                   help="[sine] lead-in cycles simulated but not recorded (default: 1)")
    g.add_argument("--rate", metavar="HZ", type=_positive,
                   help="sample rate [Hz]: [quasi-static] 50, others 1000")
    g.add_argument("--velocity", metavar="M/S", type=_positive,
                   help="[quasi-static] constant stroke velocity [m/s] (default: 0.004)")
    g.add_argument("--f-start", metavar="HZ", type=_positive,
                   help="[chirp] start frequency [Hz] (default: 0.5)")
    g.add_argument("--f-end", metavar="HZ", type=_positive,
                   help="[chirp] end frequency [Hz] (default: 16)")
    g.add_argument("--duration", metavar="S", type=_positive,
                   help="[chirp] sweep duration [s] (default: 60)")
    g.add_argument("--v-start", metavar="M/S", type=_positive,
                   help="[chirp] velocity amplitude at the start [m/s] (default: 0.05)")
    g.add_argument("--v-end", metavar="M/S", type=_positive,
                   help="[chirp] velocity amplitude at the end [m/s] (default: 1.5)")
    g.add_argument("--points", metavar="N", type=_points,
                   help="[14-speed] number of test speeds (default: 14)")
    g.add_argument("--v-min", metavar="M/S", type=_positive,
                   help="[14-speed] lowest peak velocity [m/s] (default: 0.025)")
    g.add_argument("--v-max", metavar="M/S", type=_positive,
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
    dyno.set_defaults(handler=cmd_dyno)

    # ---- demo ------------------------------------------------------------------------
    demo = sub.add_parser(
        "demo", formatter_class=_Formatter,
        help="closed-loop HIL demo: emulator + ride simulation over ROS 2, recorded",
        description="Closed-loop hardware-in-the-loop demo on this machine.\n\n"
                    "Starts the damper_emulator node (1 kHz), the ride_sim node (quarter car\n"
                    "on the minor road at 20 m/s), the CAN bridge (controller mode), the\n"
                    "skyhook controller (a process on the CAN bus) and the recorder as\n"
                    "separate processes (localhost only, own ROS_DOMAIN_ID; CAN: socketcan\n"
                    "vcan0 where the kernel has it, else a private udp_multicast group), runs\n"
                    "DURATION seconds of road, and writes under DIR: bag/ (rosbag2, MCAP),\n"
                    "ride_metrics.json, skyhook.json, demo.json, report.md, ride.png,\n"
                    "damper.png, control.png, loop.png and logs/.")
    demo.add_argument("--duration", metavar="S", type=_positive, default=20.0,
                      help="road time [s] (default: 20; at least 5 at 20 m/s)")
    demo.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime",
                      help="ride clock (default: realtime)")
    demo.add_argument("--control", choices=("skyhook", "passive"), default="skyhook",
                      help="skyhook: the reference skyhook controller commands the adaptive "
                           "damper over CAN; passive: the damper stays at sport (the bridge "
                           "still runs; default: skyhook)")
    demo.add_argument("--out", metavar="DIR", type=Path, default=Path("demo_out"),
                      help="output directory (created if missing; default: demo_out)")
    demo.set_defaults(handler=cmd_demo)

    dyno_demo = sub.add_parser(
        "dyno-demo", formatter_class=_Formatter,
        help="virtual-dyno demonstration (the paper's tests on the sport damper)",
        description="Virtual-dyno demonstration on the 'sport' damper (config/sport.yaml):\n"
                    "the quasi-static test, the chirp, the paper's validation sines\n"
                    "(1 Hz / 0.05 m, 3 Hz / 0.05 m, 12 Hz / 0.005 m) with an overlay plot\n"
                    "(paper_sines.png) and the 14-speed test; writes demo.json.")
    dyno_demo.add_argument("--duration", metavar="S", type=_positive, default=60.0,
                           help="chirp duration [s] (default: 60)")
    dyno_demo.add_argument("--out", metavar="DIR", type=Path, default=Path("demo_out"),
                           help="output directory (created if missing; default: demo_out)")
    dyno_demo.set_defaults(handler=cmd_dyno_demo)

    # ---- ROS 2 nodes -----------------------------------------------------------------
    emulate = sub.add_parser(
        "emulate", formatter_class=_Formatter,
        help="run the damper_emulator ROS 2 node (/damper/state in, /damper/force out)",
        description="Run the damper_emulator ROS 2 node until SIGINT/SIGTERM.\n\n"
                    "Parameters: groups 'emulator' (defaults: config/emulator.yaml),\n"
                    "'damper' and 'numerics' (defaults: config/sport.yaml), set with\n"
                    "  --ros-args --params-file FILE [-p emulator.rate_hz:=2000.0] ...")
    emulate.set_defaults(handler=cmd_emulate, takes_ros_args=True)
    ride_node = sub.add_parser(
        "ride", formatter_class=_Formatter,
        help="run the ride_sim ROS 2 node (quarter car closed over /damper/state, "
             "/damper/force)",
        description="Run the ride_sim ROS 2 node: one closed-loop ride against a running\n"
                    "emulator, then exit.  Parameters: groups 'quarter_car', 'simulation',\n"
                    "'road', 'ride' (defaults: config/quarter_car.yaml) and the damper's\n"
                    "'damper'/'numerics' (config/sport.yaml), set with\n"
                    "  --ros-args --params-file FILE [-p ride.clock:=lockstep] ...")
    ride_node.set_defaults(handler=cmd_ride_node, takes_ros_args=True)
    record = sub.add_parser(
        "record", formatter_class=_Formatter,
        help="record the damper topics to a rosbag2 (MCAP) bag until SIGINT/SIGTERM",
        description="Record /damper/state, /damper/force, /damper/valve_command,\n"
                    "/diagnostics and /ride/state to a rosbag2 bag with MCAP storage.\n"
                    "The bag is flushed every 0.25 s: killing the recorder loses at most\n"
                    "0.5 s and leaves a readable bag.")
    record.add_argument("--out", metavar="BAG", type=Path, required=True,
                        help="bag directory to create (must not exist or be empty)")
    record.add_argument("--topics", metavar="TOPIC", nargs="+",
                        help="record only these topics")
    record.set_defaults(handler=cmd_record, takes_ros_args=True)
    bridge = sub.add_parser(
        "bridge", formatter_class=_Formatter,
        help="run the can_bridge ROS 2 node (CAN frames of config/damper.dbc <-> topics)",
        description="Run the can_bridge ROS 2 node until SIGINT/SIGTERM.\n\n"
                    "mode dyno: DAMPER_STATE frames -> /damper/state, /damper/force ->\n"
                    "DAMPER_FORCE frames.  mode controller: VALVE_COMMAND frames ->\n"
                    "/damper/valve_command, /ride/state -> VEHICLE_MOTION frames,\n"
                    "/damper/force -> DAMPER_FORCE frames (status).  Frames with a wrong\n"
                    "length, checksum or counter are dropped and counted; silence puts a\n"
                    "fault status into DAMPER_FORCE and /diagnostics; a failed bus is\n"
                    "reopened with backoff.  Parameters (no group; defaults:\n"
                    "config/bridge.yaml): can_interface, can_channel, bitrate, mode, ...",
        epilog="examples:\n"
               f"  {PROG} bridge --ros-args -p can_interface:=socketcan -p can_channel:=vcan0\n"
               f"  {PROG} bridge --ros-args -p can_interface:=udp_multicast "
               "-p \"can_channel:='[ff11::d4:1]:43000'\" -p mode:=controller\n"
               "(a channel with a port needs the inner YAML quotes)")
    bridge.set_defaults(handler=cmd_bridge, takes_ros_args=True)
    sky = sub.add_parser(
        "skyhook", formatter_class=_Formatter,
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
    sky.add_argument("--can-interface", metavar="NAME", default="socketcan",
                     help="python-can interface (default: socketcan)")
    sky.add_argument("--can-channel", metavar="CHANNEL", default="vcan0",
                     help="channel (default: vcan0)")
    sky.add_argument("--duration", metavar="S", type=_positive, default=None,
                     help="stop after S seconds (default: until SIGINT/SIGTERM)")
    sky.add_argument("--json", metavar="FILE", type=Path, default=None,
                     help="write the controller's statistics here at the end")
    sky.set_defaults(handler=cmd_skyhook)
    replay = sub.add_parser(
        "replay", formatter_class=_Formatter,
        help="offline replay of a recorded bag through the emulator's model (no ROS)",
        description="Replay /damper/state of a recorded bag through the damper model as the\n"
                    "emulator node did, and compare with the recorded /damper/force.\n\n"
                    "The trigger is detected from the bag: every force stamp a state stamp\n"
                    "-> 'input' (one force per state sample, as in lockstep); else 'timer'\n"
                    "(one force per recorded tick: the tick's input sample is found by its\n"
                    "velocity and stroke, fault ticks give the fault output, the model steps\n"
                    "by the stamp differences).  Writes into --out DIR: replay_bag/ (the\n"
                    "state copied, the replayed force), replay.json and replay.png (recorded\n"
                    "and replayed force, their difference).  Same bag, same output.\n\n"
                    "replay.json: bag, trigger, forces, compared (model outputs compared),\n"
                    "rms_N and max_abs_N of replayed - recorded, relative_rms (to the\n"
                    "recorded force's r.m.s.), elapsed_s, recorded_duration_s,\n"
                    "speed_vs_real_time, counts.  See damper_emulator/replay.py.",
        epilog="examples:\n"
               f"  {PROG} replay demo_out/bag --out replay_out\n"
               f"  {PROG} replay demo_out/bag --out replay_out --json replay.json "
               "--params fitted.yaml")
    replay.add_argument("bag", metavar="BAG", type=Path,
                        help="rosbag2 bag directory with /damper/state and /damper/force")
    replay.add_argument("--out", metavar="DIR", type=Path, required=True,
                        help="output directory (created if missing; an earlier replay's "
                             "replay_bag/ there is replaced)")
    replay.add_argument("--json", metavar="FILE", type=Path, default=None,
                        help="also write the results to FILE (always: DIR/replay.json)")
    replay.add_argument("--params", metavar="PARAMS.yaml", type=Path, default=None,
                        help="damper parameter file (default: config/sport.yaml)")
    replay.add_argument("--emulator-params", metavar="FILE", type=Path, default=None,
                        help="params file with an 'emulator' group overriding "
                             "config/emulator.yaml (input_mode, fault_mode, ...)")
    replay.set_defaults(handler=cmd_replay)

    # ---- validate --------------------------------------------------------------------
    validate = sub.add_parser(
        "validate", formatter_class=_Formatter,
        help="compare the compressible model with measured data: r.m.s. force error "
             "per file",
        description="Simulate the compressible (hysteretic) model over the displacement\n"
                    "history of each measured-data file and compare the simulated force\n"
                    "with the measured one (docs/model.md eqs 34-35):\n"
                    "  rms_N        = sqrt(mean((F_sim - F_meas)^2))   [N]\n"
                    "  relative_rms = rms_N / sqrt(mean(F_meas^2))\n"
                    "Every sample counts, the first cycle included: the simulation starts\n"
                    "in quasi-steady equilibrium at the first sample.  The velocity is the\n"
                    "file's velocity column, or else a Savitzky-Golay derivative of the\n"
                    "displacement (cubic, window 1/20 of the dominant period).\n\n"
                    "Results are written to the JSON file (--json) as\n"
                    '  {"params_file": ..., "files": {NAME: {"rms_N": .., "relative_rms": ..,\n'
                    "   samples, peak forces, velocity source, ...}}}\n"
                    "(NAME: the file's base name) and printed as a table on stdout.",
        epilog="examples:\n"
               f"  {PROG} validate --params config/sport.yaml out/sine_1hz.csv "
               "out/sine_3hz.csv\n"
               f"  {PROG} validate --params fitted.yaml --report val_out data/*.csv")
    validate.add_argument("data", metavar="DATA.csv", type=Path, nargs="+",
                          help="measured-data files (CSV or .csv.gz: time [s], "
                               "displacement [m], force [N], optional velocity [m/s]); "
                               "base names must differ")
    validate.add_argument("--params", metavar="PARAMS.yaml", type=Path, required=True,
                          help="damper parameter file to validate (ROS 2 params YAML)")
    validate.add_argument("--json", metavar="FILE", type=Path, default=None,
                          help="results file (default: validation.json in the --report "
                               "directory when given, else in the current directory)")
    validate.add_argument("--report", metavar="DIR", type=Path, default=None,
                          help="also write figures into DIR (created if missing): per file "
                               "validate_<name>.png (measured and simulated force-velocity "
                               "and force-displacement loops, force error vs time) and "
                               "validation_summary.png (relative r.m.s. per file)")
    validate.set_defaults(handler=cmd_validate)

    # ---- identify ----------------------------------------------------------------------
    ident = sub.add_parser(
        "identify", formatter_class=_Formatter,
        help="fit the model's parameters to a quasi-static and a chirp test",
        description="Identify gas spring, friction and both valves from dyno data "
                    "(docs/model.md §3).\n\n"
                    "Quasi-static fit (eq 37) and chirp fit of the incompressible valve\n"
                    "model after the paper's hysteresis filter, alternated until they agree;\n"
                    "least squares with an exact Jacobian, log-scaled parameters and start\n"
                    "values derived from the data.  The chirp's valve flow is corrected for\n"
                    "oil compressibility with eq 2 (--no-compressibility-correction gives the\n"
                    "paper's plain procedure).  Geometry, gamma, viscosity and alpha come from\n"
                    "--base (the data sheet).  Writes PARAMS.yaml (loadable by every command\n"
                    "and the emulator), a JSON with the fit statistics and a report.")
    ident.add_argument("--quasi-static", metavar="QS.csv", type=Path, required=True,
                       nargs="+",
                       help="quasi-static test (constant low velocity, both directions); "
                            "several files are fitted together")
    ident.add_argument("--chirp", metavar="CHIRP.csv", type=Path, required=True, nargs="+",
                       help="chirp test (swept sine with growing velocity amplitude); "
                            "several files (e.g. sines of different speeds) are fitted "
                            "together, each file's flow worked out on its own")
    ident.add_argument("--fix", metavar="[SIDE.]NAME=VALUE", action="append", default=[],
                       help="hold a valve parameter at VALUE instead of fitting it; NAME is "
                            "one of k_leak, k_port, k_spring, preload_pa, smoothing_g; SIDE "
                            "(rebound or compression) defaults to both; repeatable")
    ident.add_argument("--out", metavar="PARAMS.yaml", type=Path, required=True,
                       help="identified parameter file to write (ROS 2 params YAML)")
    ident.add_argument("--base", metavar="BASE.yaml", type=Path, default=None,
                       help="fixed parameters (geometry, gamma, nu, alpha) and numerics "
                            "(default: config/sport.yaml)")
    ident.add_argument("--json", metavar="FILE", type=Path, default=None,
                       help="fit results as JSON (default: PARAMS.json beside --out)")
    ident.add_argument("--report", metavar="DIR", type=Path, default=None,
                       help="write the report figures (PNG) into DIR")
    ident.add_argument("--fit-alpha", action="store_true",
                       help="also fit the oil compressibility alpha (eq 1) to the chirp's "
                            "hysteresis: a bounded search, each alpha with a complete "
                            "identification, minimising the compressible model's r.m.s. "
                            "force error over the whole chirp")
    ident.add_argument("--alpha-bounds", metavar=("LO", "HI"), type=float, nargs=2,
                       default=None,
                       help="alpha search range [1/Pa] (default: 0.1x to 100x the base "
                            "alpha)")
    ident.add_argument("--no-compressibility-correction", action="store_true",
                       help="use the rigid-oil valve flow |v|(A_pt − A_rod) as the paper does")
    ident.set_defaults(handler=cmd_identify)

    # ---- diagnose ----------------------------------------------------------------------
    diag = sub.add_parser(
        "diagnose", formatter_class=_Formatter,
        help="close the loop on measured data: find the effect the identified model lacks",
        description="Trace the identified model's residual to the effects it lacks.  The\n"
                    "paper's parameters are re-identified jointly with each candidate effect\n"
                    "(friction, thermal, cavitation, valve dynamics, compliance, end stops,\n"
                    "air entrainment, position-dependent damping, gas-spring heat transfer)\n"
                    "on the identification files (--quasi-static, --chirp), simulated whole;\n"
                    "each is scored by the r.m.s. reduction on the held-out files (--validate)\n"
                    "and penalised for its parameters (BIC with the residual's effective\n"
                    "sample size).  Forward selection adds the best significant effect and\n"
                    "tests the rest on top, up to two.  family 'none': the refitted paper's\n"
                    "model is within the floor (1 % of the force r.m.s. or 2x the noise) or\n"
                    "without structure; 'other': structure remains that no candidate\n"
                    "explains.\n\n"
                    "JSON (--json): {family, effect, significant, rms_before, rms_after,\n"
                    "effects: [{effect, family, parameters, fitted, held_out_gain}],\n"
                    "candidates: [{effect, family, score, ...}], refit, rounds, thresholds,\n"
                    "...}; rms_before: the identified model's residual r.m.s. [N] per file,\n"
                    "rms_after: the model after the diagnosis (re-identified, with the\n"
                    "effects).  Data files as for validate (CSV or .csv.gz; an optional\n"
                    "temperature column [°C] drives the viscosity-temperature candidate).",
        epilog="examples:\n"
               f"  {PROG} diagnose --params fitted.yaml --quasi-static qs.csv --chirp "
               "chirp.csv \\\n      --validate sine_1hz.csv sine_3hz.csv --json diag.json "
               "--report diag_out\n"
               f"  {PROG} diagnose --params fitted.yaml --quasi-static qs.csv --chirp "
               "chirp.csv \\\n      --validate sine_*.csv --effects lugre_friction,valve_lag "
               "--json d.json")
    diag.add_argument("--params", metavar="PARAMS.yaml", type=Path, required=True,
                      help="identified parameter file (from identify, on the same files); "
                           "the start and the centre of the bounds of the re-identification")
    diag.add_argument("--quasi-static", metavar="QS.csv", type=Path, required=True, nargs="+",
                      help="quasi-static test file(s): fitted")
    diag.add_argument("--chirp", metavar="CHIRP.csv", type=Path, required=True, nargs="+",
                      help="chirp test file(s): fitted")
    diag.add_argument("--validate", metavar="DATA.csv", type=Path, required=True, nargs="+",
                      help="held-out file(s), e.g. the validation sines: scored, never fitted")
    diag.add_argument("--json", metavar="FILE", type=Path, required=True,
                      help="results file")
    diag.add_argument("--report", metavar="DIR", type=Path, default=None,
                      help="also write report.md, overlay_<file>.png per held-out file, "
                           "ranking.png and params_with_effect.yaml into DIR")
    diag.add_argument("--effects", metavar="NAMES", default=None,
                      help="comma-separated subset of the candidates (default: all): "
                           "lugre_friction, viscosity_temperature, cavitation, valve_lag, "
                           "series_compliance, end_stops, air_entrainment, bypass_groove, "
                           "gas_heat_transfer")
    diag.add_argument("--jobs", metavar="N", type=_pos_int, default=None,
                      help="fit the candidates in N processes (default: the CPU count, at "
                           "most 4)")
    diag.set_defaults(handler=cmd_diagnose)

    # ---- ride-study --------------------------------------------------------------------
    ride = sub.add_parser(
        "ride-study", formatter_class=_Formatter,
        help="quarter-car ride studies: the paper's figures 10 (random road), 11 (speed "
             "sweep) and 13 (pothole); the adaptive damper (passive vs skyhook)",
        description="Quarter-car ride studies after Simms & Crolla (docs/model.md §5), for the\n"
                    "damper representations linear (C_s = 2622 N s/m at the wheel), 14speed\n"
                    "(14-speed test of the hysteretic model), nonlinear (the hysteretic model\n"
                    "in the 1 kHz loop) and incompressible (extra column):\n"
                    "  10  random minor road (eq 39), 500 m at 20 m/s, mean and spread over\n"
                    "      road seeds; r.m.s. and peak SWS, Wk-weighted body acceleration and\n"
                    "      dynamic tyre load beside the paper's values; the linear car's\n"
                    "      frequency-domain prediction; the paper's DTL claim checked\n"
                    "  11  weighted acceleration r.m.s. against speed (5..35 m/s) in a\n"
                    "      process pool\n"
                    "  13  the project's pothole at 10 m/s\n"
                    "  adaptive  the adaptive damper (docs/model.md §6) on the figure-10 road:\n"
                    "      passive sport (valve command 1), passive comfort (0) and the\n"
                    "      skyhook law (--skyhook, config/skyhook.yaml; command held at its\n"
                    "      rate, solenoid lag in the model); SWS, Wk-weighted acceleration and\n"
                    "      DTL r.m.s., mean ± std over seeds, per seed, ratios to sport\n"
                    "Road, band, seeds and pothole come from the config's 'road' group\n"
                    "(config/quarter_car.yaml); the options below override them.  Results go\n"
                    "to --json (per representation: sws_rms [m], accel_w_rms [m/s^2],\n"
                    "accel_rms, dtl_rms [N], *_peak_pos / *_peak_neg, spread over seeds, the\n"
                    "paper's values and ratios); a table is printed on stdout.  See\n"
                    "docs/ride_study.md.",
        epilog="examples:\n"
               f"  {PROG} ride-study --figure 10 --json fig10.json --report docs/ride_study\n"
               f"  {PROG} ride-study --figure 11 --seeds 5 --workers 2 --json fig11.json\n"
               f"  {PROG} ride-study --figure 13 --speed 10 --json fig13.json\n"
               f"  {PROG} ride-study --figure adaptive --json adaptive.json --out "
               "docs/ride_study")
    ride.add_argument("--figure", required=True, choices=("10", "11", "13", "adaptive"),
                      help="which study: 10 random road, 11 speed sweep, 13 pothole, "
                           "adaptive (passive sport / comfort vs skyhook)")
    ride.add_argument("--json", metavar="FILE", type=Path, required=True,
                      help="results file (JSON; parent directories are created)")
    ride.add_argument("--config", metavar="CONFIG.yaml", type=Path, default=None,
                      help="quarter-car params file with an optional 'road' group "
                           "(default: config/quarter_car.yaml)")
    ride.add_argument("--seeds", metavar="N", type=_pos_int, default=None,
                      help="[10, 11, adaptive] road seeds 0..N-1, the same for every "
                           "damper (default: road.seeds, 5)")
    ride.add_argument("--length", metavar="M", type=_positive, default=None,
                      help="[10, 11, adaptive] length of random road evaluated [m] "
                           "(default: 500)")
    ride.add_argument("--speed", metavar="V", type=_positive, nargs="+", default=None,
                      help="speed [m/s]: [10, adaptive] one value (default 20), [13] one "
                           "value (default 10), [11] the sweep's speeds (default 5 10 ... 35)")
    ride.add_argument("--band", metavar=("NMIN", "NMAX"), type=_positive, nargs=2,
                      default=None,
                      help="[10, 11, adaptive] synthesised road band [cycles/m] (default: "
                           "0.01 0.8, the band the paper's figure 10 implies)")
    ride.add_argument("--band-scaling", choices=("temporal", "spatial"), default=None,
                      help="[11] keep the band fixed in Hz as at 20 m/s (temporal, default) "
                           "or in cycles/m (spatial)")
    ride.add_argument("--amplitudes", choices=("deterministic", "random"), default=None,
                      help="[10, 11, adaptive] road synthesis: exact spectrum with random "
                           "phases (deterministic, default) or random amplitudes too")
    ride.add_argument("--workers", metavar="N", type=_pos_int, default=None,
                      help="[11] worker processes (default: all cores)")
    ride.add_argument("--report", "--out", metavar="DIR", dest="report", type=Path,
                      default=None,
                      help="also write the figures (PNG) into DIR: [10] ride_sws_2s.png, "
                           "ride_psd.png, ride_band_sensitivity.png; [11] "
                           "ride_speed_sweep.png; [13] ride_pothole.png; [adaptive] "
                           "ride_adaptive_bars.png, ride_adaptive_history.png")
    ride.add_argument("--skyhook", metavar="SKYHOOK.yaml", type=Path, default=None,
                      help="[adaptive] skyhook params file (default: config/skyhook.yaml)")
    ride.set_defaults(handler=cmd_ride_study)
    ride.error = lambda message: ride.exit(  # type: ignore[method-assign]
        2, f"{ride.prog}: error: {_one_line(message)}\n")  # one line, no usage block
    return parser


# --------------------------------------------------------------------------------------
# helpers


def _progress(path: Path) -> None:
    print(f"wrote {path}", file=sys.stderr, flush=True)


def _check_unique_names(paths: Sequence[Path]) -> None:
    """Results are keyed by base name: refuse two files with the same one, before any
    work."""
    seen: dict[str, Path] = {}
    for p in paths:
        if p.name in seen:
            raise CliError(f"two data files have the base name {p.name!r} ({seen[p.name]} "
                           f"and {p}): results are keyed by base name")
        seen[p.name] = p


def _write_json(path: Path, doc: dict[str, Any]) -> None:
    path.write_text(json.dumps(doc, indent=2) + "\n")
    _progress(path)


def _load_model(params: Path | None):
    from damper_emulator.model.compressible import DamperModel
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config

    cfg = load_config(params)
    return DamperModel(cfg), str(params if params is not None else DEFAULT_PARAMS_FILE)


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


# --------------------------------------------------------------------------------------
# subcommands


def cmd_dyno(args: argparse.Namespace) -> int:
    opts = _protocol_options(args)  # before the heavy imports: a typo fails fast
    model, params_file = _load_model(args.params)
    if args.over_can:
        return _dyno_over_can(args, opts, model, params_file)
    return _run_dyno(args, opts, model, params_file)


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

    common = dict(noise_std=args.noise_std, seed=args.seed, progress=_progress, engine=engine)
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
    _write_json(out / "dyno.json", {
        "protocol": args.protocol,
        "options": {**opts, "noise_std_n": args.noise_std, "seed": args.seed},
        "params_file": params_file,
        "damper": model.cfg.damper.name,
        "files": summary["files"] + ["dyno.json"],
        "summary": summary,
        **(extra or {}),
    })
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from damper_emulator.hil_demo import DemoError, run_demo

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    try:
        summary = run_demo(args.out, args.duration, clock=args.clock, control=args.control,
                           progress=progress)
    except DemoError as exc:
        raise CliError(str(exc)) from None
    m = summary["ride"]["metrics"]
    loop = summary["emulator_loop"] or {}
    print(f"demo finished in {summary['elapsed_s']:.0f} s: SWS r.m.s. {m['sws_rms'] * 1e3:.2f} "
          f"mm, Wk body acceleration r.m.s. {m['accel_w_rms']:.3f} m/s², DTL r.m.s. "
          f"{m['dtl_rms']:.0f} N; emulator loop p99 {loop.get('period_p99_us', float('nan')):.0f}"
          f" µs; bag and report in {args.out}", file=sys.stderr)
    return 0


def cmd_dyno_demo(args: argparse.Namespace) -> int:
    from damper_emulator.dyno import plots, runner
    from damper_emulator.dyno.measured import read_measured_csv

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    model, params_file = _load_model(None)
    steps = 4 + len(PAPER_SINES)
    results: dict[str, Any] = {}
    files: list[str] = []
    k = 0

    def step(label: str) -> None:
        nonlocal k
        k += 1
        print(f"[{k}/{steps}] {label} ...", file=sys.stderr, flush=True)

    step("quasi-static test (4 mm/s, ±75 mm, 150 s)")
    results["quasi_static"] = runner.run_quasi_static(model, out, progress=_progress)
    step(f"chirp 0.5–16 Hz, {args.duration:g} s")
    results["chirp"] = runner.run_chirp(model, out, duration=args.duration,
                                        progress=_progress)
    sines = []
    for freq, amp in PAPER_SINES:
        step(f"sine {freq:g} Hz, {amp * 1e3:g} mm")
        s = runner.run_sine(model, out, freq, amp, progress=_progress)
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
    _progress(overlay)
    step("14-speed test (0.025 m amplitude, 0.025–1.5 m/s)")
    results["14speed"] = runner.run_fourteen_speed(model, out, progress=_progress)
    for r in results.values():
        files += r["files"]
    files += [overlay.name, "demo.json"]
    elapsed = time.perf_counter() - started
    _write_json(out / "demo.json", {
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


def cmd_emulate(args: argparse.Namespace) -> int:
    from damper_emulator.ros.common import spin_node
    from damper_emulator.ros.emulator import EmulatorNode

    return spin_node(EmulatorNode, args.ros_args)


def cmd_ride_node(args: argparse.Namespace) -> int:
    from damper_emulator.ros.common import spin_node
    from damper_emulator.ros.ride import RideNode

    return spin_node(RideNode, args.ros_args)


def cmd_bridge(args: argparse.Namespace) -> int:
    from can_bridge.node import BridgeNode
    from damper_emulator.ros.common import spin_node

    return spin_node(BridgeNode, args.ros_args)


def cmd_skyhook(args: argparse.Namespace) -> int:
    import signal
    import threading

    from can_bridge.bus import BusConfig, CanBusError, open_bus
    from can_bridge.dbc import load_database
    from can_bridge.skyhook_controller import run_skyhook
    from ride_sim.skyhook import load_skyhook, resolve_rates

    params = load_skyhook(args.params)
    model = _load_model(args.damper_params)[0] if params.rates_from == "model" \
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
        _write_json(args.json, stats.as_dict())
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    from damper_emulator.ros.common import spin_node
    from damper_emulator.ros.recorder import RecorderNode

    return spin_node(lambda: RecorderNode(args.out, args.topics), args.ros_args)


def cmd_replay(args: argparse.Namespace) -> int:
    from damper_emulator.bag import BagError
    from damper_emulator.replay import run_replay

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    print(f"replaying {args.bag} ...", file=sys.stderr, flush=True)
    try:
        doc = run_replay(args.bag, args.out, json_path=args.json, params_file=args.params,
                         emulator_params_file=args.emulator_params, progress=progress)
    except BagError as exc:
        raise CliError(str(exc)) from None
    rms = (f"r.m.s. {doc['rms_N']:.3g} N, max {doc['max_abs_N']:.3g} N"
           if doc["rms_N"] is not None else "no model output to compare")
    print(f"replayed {doc['forces']} forces ({doc['trigger']} trigger, "
          f"{doc['recorded_duration_s']:.1f} s recorded) in {doc['elapsed_s'] * 1e3:.0f} ms "
          f"({doc['speed_vs_real_time'] or float('inf'):.0f}x real time); {rms} over "
          f"{doc['compared']} "
          f"model outputs", file=sys.stderr)
    return 0


def cmd_validate(args: argparse.Namespace) -> int:
    paths: list[Path] = args.data
    _check_unique_names(paths)
    from damper_emulator import validation
    from damper_emulator.dyno.measured import read_measured_csv

    json_path: Path = args.json if args.json is not None else (
        (args.report if args.report is not None else Path(".")) / "validation.json")
    model, params_file = _load_model(args.params)
    datasets = [read_measured_csv(p) for p in paths]  # a malformed file fails before work
    results: dict[str, Any] = {}
    n = len(datasets)
    for k, data in enumerate(datasets, 1):
        print(f"[{k}/{n}] validating {data.name} ({len(data)} samples, "
              f"{data.duration_s:.3g} s) ...", file=sys.stderr, flush=True)
        results[data.name] = validation.validate_file(model, data)
    json_path.parent.mkdir(parents=True, exist_ok=True)
    _write_json(json_path, {
        "params_file": params_file,
        "files": {name: validation.json_summary(r) for name, r in results.items()},
    })
    if args.report is not None:
        report: Path = args.report
        report.mkdir(parents=True, exist_ok=True)
        label = f"{args.params.name}, damper '{model.cfg.damper.name}'"
        for name, r in results.items():
            png = report / f"validate_{validation.report_stem(name)}.png"
            _progress(validation.plot_validation(
                png, r, title=f"{name} vs compressible model ({label}): "
                              f"{validation.rms_caption(r)}"))
        _progress(validation.plot_relative_rms_summary(
            report / "validation_summary.png", results,
            title=f"Validation of {args.params.name}: relative r.m.s. force error per file "
                  "(label: r.m.s. in N)"))
    width = max(len("file"), *(len(name) for name in results))
    print(f"{'file':<{width}}  {'samples':>8}  {'rms [N]':>9}  {'relative':>9}  "
          f"{'peak F meas [N]':>17}  {'peak F sim [N]':>17}")
    for name, r in results.items():
        rel = (f"{100.0 * r['relative_rms']:8.3f}%" if r["relative_rms"] is not None
               else f"{'-':>9}")
        print(f"{name:<{width}}  {r['samples']:>8d}  {r['rms_N']:>9.3f}  {rel}  "
              f"{r['peak_force_measured_rebound_n']:>+8.0f}/"
              f"{r['peak_force_measured_compression_n']:<+8.0f}  "
              f"{r['peak_force_simulated_rebound_n']:>+8.0f}/"
              f"{r['peak_force_simulated_compression_n']:<+8.0f}")
    return 0


def cmd_diagnose(args: argparse.Namespace) -> int:
    from damper_emulator.diagnose.selection import diagnose
    from damper_emulator.dyno.measured import read_measured_csv
    from damper_emulator.params import EXTENSION_TYPES

    started = time.perf_counter()
    effects = None
    if args.effects is not None:
        effects = [e.strip() for e in args.effects.split(",") if e.strip()]
        unknown = [e for e in effects if e not in EXTENSION_TYPES]
        if unknown or not effects:
            raise CliError(f"--effects: unknown effect {unknown[0] if unknown else '(none)'!r}"
                           f" (one of {', '.join(EXTENSION_TYPES)})")
    _check_unique_names([*args.quasi_static, *args.chirp, *args.validate])
    model, params_file = _load_model(args.params)
    if model.cfg.damper.extensions is not None:
        raise CliError(f"{params_file}: already holds damper.extensions "
                       f"({', '.join(model.cfg.damper.extensions.active())}); diagnose needs "
                       "the identified model without them")
    fit = [read_measured_csv(p) for p in [*args.quasi_static, *args.chirp]]
    held = [read_measured_csv(p) for p in args.validate]
    print(f"diagnosing {params_file}: fit on {', '.join(d.name for d in fit)}, held out "
          f"{', '.join(d.name for d in held)}", file=sys.stderr, flush=True)
    import os

    jobs = args.jobs if args.jobs is not None else min(os.cpu_count() or 1, 4)
    result = diagnose(model, fit, held, effects, jobs=jobs,
                      n_quasi_static=len(args.quasi_static),
                      progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    doc = {"params_file": params_file, **result.to_json()}
    if args.report is not None:
        from damper_emulator.diagnose.report import write_report

        files = write_report(result, args.report, params_file,
                             progress=lambda msg: print(msg, file=sys.stderr, flush=True))
        doc["report_dir"] = str(args.report)
        doc["report_files"] = [p.name for p in files]
    args.json.parent.mkdir(parents=True, exist_ok=True)
    _write_json(args.json, doc)
    width = max(len("file"), *(len(n) for n in result.rms_before))
    print(f"diagnosis: {result.family}" + "".join(
        f"{' +' if k else ''} ({s.candidate.effect}, held-out r.m.s. -{100 * s.score:.1f} %)"
        for k, s in enumerate(result.steps)))
    print(f"{'file':<{width}}  {'role':>8}  {'before [N]':>10}  {'after [N]':>10}")
    for r in result.records:
        print(f"{r.name:<{width}}  {'held out' if r.held_out else 'fit':>8}  "
              f"{result.rms_before[r.name]:>10.2f}  {result.rms_after[r.name]:>10.2f}")
    print(f"finished in {time.perf_counter() - started:.1f} s", file=sys.stderr)
    return 0


def _fixed_valve_parameters(specs: Sequence[str]) -> dict[str, dict[str, float]]:
    """``--fix`` options ``[SIDE.]NAME=VALUE`` → ``{side: {name: value}}``."""
    from damper_emulator.identify.valves import NAMES

    fixed: dict[str, dict[str, float]] = {}
    for spec in specs:
        key, sep, text = spec.partition("=")
        side, dot, name = key.strip().rpartition(".")
        sides = [side] if dot else ["rebound", "compression"]
        if not sep or name not in NAMES or any(s not in ("rebound", "compression")
                                                  for s in sides):
            raise CliError(f"--fix {spec!r}: expected [rebound.|compression.]NAME=VALUE with "
                           f"NAME one of {', '.join(NAMES)}")
        try:
            value = float(text)
        except ValueError:
            raise CliError(f"--fix {spec!r}: {text!r} is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise CliError(f"--fix {spec!r}: the value must be a positive number")
        for one in sides:
            fixed.setdefault(one, {})[name] = value
    return fixed


def cmd_identify(args: argparse.Namespace) -> int:
    from damper_emulator.dyno.measured import read_measured_csv
    from damper_emulator.identify.pipeline import identify
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config, save_config

    started = time.perf_counter()
    base = load_config(args.base)
    fixed = _fixed_valve_parameters(args.fix)
    qs = [read_measured_csv(p) for p in args.quasi_static]
    chirp = [read_measured_csv(p) for p in args.chirp]
    print(f"identifying from {', '.join(d.name for d in qs)} "
          f"({sum(len(d) for d in qs)} samples) and {', '.join(d.name for d in chirp)} "
          f"({sum(len(d) for d in chirp)} samples) ...", file=sys.stderr, flush=True)
    import numpy as np

    for d in qs:
        v_peak = float(np.percentile(np.abs(d.velocity_or_derivative()), 99))
        if v_peak > QUASI_STATIC_WARN_SPEED_M_S:
            print(f"warning: {d.name} is not slow (99th-percentile speed {v_peak:.3g} m/s, "
                  f"the paper's quasi-static test runs at 0.004 m/s): its viscous force "
                  "will bias the gas spring and friction", file=sys.stderr, flush=True)
    result = identify(qs, chirp, base, progress=lambda m: print(m, file=sys.stderr,
                                                                 flush=True),
                      correct_compressibility=not args.no_compressibility_correction,
                      fixed=fixed, fit_alpha=args.fit_alpha,
                      alpha_bounds_per_pa=args.alpha_bounds)
    cfg = result.config
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_config(cfg, args.out)
    _progress(args.out)
    json_path = args.json or args.out.with_suffix(".json")
    doc = {"params_file": str(args.out),
           "base_params_file": str(args.base or DEFAULT_PARAMS_FILE),
           "quasi_static_file": str(args.quasi_static[0]), "chirp_file": str(args.chirp[0]),
           "quasi_static_files": [str(p) for p in args.quasi_static],
           "chirp_files": [str(p) for p in args.chirp], "fixed": fixed,
           "compressibility_correction": not args.no_compressibility_correction,
           **result.as_dict()}
    if args.report is not None:
        from damper_emulator.identify.report import write_report

        write_report(args.report, result, progress=_progress)
        doc["report_dir"] = str(args.report)
    doc["elapsed_s"] = round(time.perf_counter() - started, 3)
    _write_json(json_path, doc)
    print(f"identified in {doc['elapsed_s']:.1f} s: quasi-static r.m.s. "
          f"{result.quasi_static.rms:.2f} N, rebound {result.rebound.rms:.2f} N, "
          f"compression {result.compression.rms:.2f} N", file=sys.stderr)
    return 0


#: ride-study options that do not apply to a figure: figure → option dests
_RIDE_IGNORED = {13: ("seeds", "length", "band", "band_scaling", "amplitudes", "workers",
                      "skyhook"),
                 10: ("band_scaling", "workers", "skyhook"), 11: ("skyhook",),
                 "adaptive": ("band_scaling", "workers")}


def cmd_ride_study(args: argparse.Namespace) -> int:
    fig = int(args.figure) if args.figure.isdigit() else args.figure
    if args.band is not None and not args.band[0] < args.band[1]:
        raise CliError(f"--band {args.band[0]:g} {args.band[1]:g}: NMIN must be below NMAX")
    if args.speed is not None and fig != 11 and len(args.speed) != 1:
        raise CliError(f"--speed takes one value for --figure {fig} (a list only for 11)")
    for dest in _RIDE_IGNORED[fig]:
        if getattr(args, dest) is not None:
            print(f"note: --{dest.replace('_', '-')} does not apply to --figure {fig}; "
                  "ignored", file=sys.stderr)
    from ride_sim import study
    from ride_sim.params import load_ride_config

    cfg = load_ride_config(args.config)
    overrides: dict[str, Any] = {}
    if fig != 13:
        overrides.update(seeds=args.seeds, length_m=args.length,
                         band_cycles_per_m=tuple(args.band) if args.band else None,
                         amplitudes=args.amplitudes)
    if fig == 11:
        overrides.update(band_scaling=args.band_scaling,
                         sweep_speeds_m_s=tuple(args.speed) if args.speed else None)
    elif args.speed is not None:
        overrides["pothole_speed_m_s" if fig == 13 else "speed_m_s"] = args.speed[0]
    settings = study.StudySettings.from_config(cfg, **overrides)
    if fig == "adaptive":
        from ride_sim.skyhook import load_skyhook

        skyhook = load_skyhook(args.skyhook)

    def progress(message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    if fig == 10:
        result = study.figure10(settings, progress=progress)
    elif fig == 11:
        result = study.figure11(settings, workers=args.workers, progress=progress)
    elif fig == "adaptive":
        result = study.adaptive_study(settings, skyhook, progress=progress)
    else:
        result = study.figure13(settings, progress=progress)
    doc = result.doc
    if args.report is not None:
        from ride_sim import plots

        report: Path = args.report
        report.mkdir(parents=True, exist_ok=True)
        if fig == 10:
            files = [plots.plot_sws_history(report / "ride_sws_2s.png", result),
                     plots.plot_psds(report / "ride_psd.png", result, settings),
                     plots.plot_band_sensitivity(report / "ride_band_sensitivity.png",
                                                 settings)]
        elif fig == 11:
            files = [plots.plot_speed_sweep(report / "ride_speed_sweep.png", doc, settings)]
        elif fig == "adaptive":
            files = [plots.plot_adaptive_bars(report / "ride_adaptive_bars.png", doc),
                     plots.plot_adaptive_history(report / "ride_adaptive_history.png",
                                                 result)]
        else:
            files = [plots.plot_pothole(report / "ride_pothole.png", result)]
        for path in files:
            _progress(path)
        doc["report_dir"] = str(report)
        doc["report_files"] = [p.name for p in files]
    args.json.parent.mkdir(parents=True, exist_ok=True)
    _write_json(args.json, doc)
    print(doc["title"])
    if fig == 11:
        print(study.sweep_table(doc))
        for key in ("crossing_linear_nonlinear_m_s", "crossing_linear_14speed_m_s"):
            if key in doc:
                print(f"{key}: {', '.join(f'{v:.1f}' for v in doc[key]) or 'none'} "
                      f"(paper: near {doc['paper_crossing_m_s']:g} m/s)")
    elif fig == "adaptive":
        print(study.adaptive_table(doc))
    else:
        print(study.comparison_table(doc))
        claim = doc.get("claim")
        if claim:
            print(f"claim (hysteretic vs 14-speed, {claim['seeds']} seeds): r.m.s. DTL "
                  f"{100 * claim['dtl_rms_reduction']:.1f} % lower (paper ~6 %: "
                  f"{claim['verdict']['dtl_rms']}), peak DTL "
                  f"{100 * claim['dtl_peak_reduction']:.1f} % lower (paper ~10 %: "
                  f"{claim['verdict']['dtl_peak_abs']})")
    print(f"finished in {doc['elapsed_s']:.1f} s", file=sys.stderr)
    return 0


# --------------------------------------------------------------------------------------
# entry point


def _one_line(text: str) -> str:
    return " ".join(str(text).split()) or "unknown error"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (2 for any user error)."""
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args: list[str] = []
    if "--ros-args" in argv:  # rclpy's own arguments, for the node subcommands
        i = argv.index("--ros-args")
        argv, ros_args = argv[:i], argv[i + 1:]
    args = parser.parse_args(argv)  # usage errors: argparse prints usage, exits 2
    args.ros_args = ros_args
    if ros_args and not getattr(args, "takes_ros_args", False):
        parser.error(f"{args.command} does not take --ros-args")
    try:
        return args.handler(args)
    except CliError as exc:
        print(f"{PROG}: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"{PROG}: error: {_one_line(where + (exc.strerror or str(exc)))}",
              file=sys.stderr)
        return 2
    except ValueError as exc:  # ParameterError, MeasuredDataError, bad option values
        print(f"{PROG}: error: {_one_line(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
