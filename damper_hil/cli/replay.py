"""``damper-hil replay``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from damper_hil.cli.common import PROG, CliError, Formatter


def add_parser(sub) -> None:
    replay = sub.add_parser(
        "replay", formatter_class=Formatter,
        help="offline replay of a recorded bag or CAN log through the emulator's model "
             "(no ROS)",
        description="Replay /damper/state of a recorded bag through the damper model as the\n"
                    "emulator node did, and compare with the recorded /damper/force.\n\n"
                    "A CAN log (.blf, .asc: --can-log of bridge, hybrid, virtual-rig, or a\n"
                    "dyno's own) replays too, its frames checked and decoded through the\n"
                    "CAN database: DAMPER_STATE frames are the inputs and DAMPER_FORCE the\n"
                    "recorded outputs (a dyno and the emulator); else DYNO_FEEDBACK frames\n"
                    "are both, the measured stroke in and the measured force to compare\n"
                    "with (a physical damper: the model against it).  See\n"
                    "can_bridge/log_input.py.\n\n"
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
                    "speed_vs_real_time, compute_s (the model's part), command_s (the\n"
                    "whole command), counts.  See damper_emulator/replay.py.",
        epilog="examples:\n"
               f"  {PROG} replay demo_out/bag --out replay_out\n"
               f"  {PROG} replay demo_out/bag --out replay_out --json replay.json "
               "--params fitted.yaml\n"
               f"  {PROG} replay hybrid_out/run.blf --out replay_hybrid --params "
               "config/prototype.yaml")
    replay.add_argument("bag", metavar="BAG", type=Path,
                        help="rosbag2 bag directory with /damper/state and /damper/force, "
                             "or a CAN log (.blf, .asc)")
    replay.add_argument("--dbc", metavar="FILE", type=Path, default=None,
                        help="CAN database of a CAN log (default: config/damper.dbc)")
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
    replay.set_defaults(handler=run, hard_exit=True)   # see damper_hil.cli.entry


def run(args: argparse.Namespace) -> int:
    from damper_emulator.bag import BagError
    from damper_emulator.replay import run_replay

    reader = None
    # by name, as can_bridge.can_log.SUFFIXES: a bag's replay imports no CAN code
    if args.bag.suffix.lower() in (".blf", ".asc"):
        from can_bridge.log_input import read_can_log

        def reader(path: Path):
            return read_can_log(path, args.dbc)
    elif args.dbc is not None:
        raise CliError("--dbc is for a CAN log (.blf, .asc), not a bag")

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    print(f"replaying {args.bag} ...", file=sys.stderr, flush=True)
    try:
        doc = run_replay(args.bag, args.out, json_path=args.json, params_file=args.params,
                         emulator_params_file=args.emulator_params, progress=progress,
                         reader=reader)
    except BagError as exc:
        raise CliError(str(exc)) from None
    rms = (f"r.m.s. {doc['rms_N']:.3g} N, max {doc['max_abs_N']:.3g} N"
           if doc["rms_N"] is not None else "no model output to compare")
    print(f"replayed {doc['forces']} forces ({doc['trigger']} trigger, "
          f"{doc['recorded_duration_s']:.1f} s recorded) in {doc['elapsed_s'] * 1e3:.0f} ms "
          f"({doc['speed_vs_real_time'] or float('inf'):.0f}x real time; the model "
          f"{doc['compute_speed_vs_real_time'] or float('inf'):.0f}x); {rms} over "
          f"{doc['compared']} model outputs; {doc['command_s']:.1f} s in all",
          file=sys.stderr)
    return 0
