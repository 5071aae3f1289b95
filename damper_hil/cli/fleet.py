"""``damper-hil fleet``."""

from __future__ import annotations

import argparse
from pathlib import Path

from damper_hil.cli.common import PROG, Formatter, add_engine_options, parse_effects, say


def add_parser(sub) -> None:
    fleet = sub.add_parser(
        "fleet", formatter_class=Formatter,
        help="identify, validate (and diagnose) many dampers' dyno tests on Dask",
        description="Every subfolder of DATA_DIR is one damper's test set: measured-data\n"
                    "files named by protocol (quasi_static*.csv and chirp*.csv: identified\n"
                    "on; sine_*.csv: validated on; .csv.gz, .tdms, .mf4 too) and an optional\n"
                    "base.yaml, the damper's data sheet (as identify --base; default\n"
                    "config/sport.yaml).  Each damper is one Dask task: identify, validate\n"
                    "on the sines and, with --diagnose, diagnose, with the single commands'\n"
                    "defaults (docs/fleet.md).\n\n"
                    "Writes OUT/<id>/ (identified.yaml, identified.json, validation.json,\n"
                    "diagnosis.json, result.json), OUT/results.csv and OUT/results.parquet\n"
                    "(one row per damper: parameters with standard errors, validation\n"
                    "r.m.s., diagnosis, flags, status, wall time) and OUT/summary.md with\n"
                    "plots.  A damper whose files are bad is one row with status 'error'\n"
                    "and the reason; the others go on.  Run again on the same OUT to go on\n"
                    "after an interruption: finished dampers are not redone.\n\n"
                    "Engine: --workers N starts a local Dask cluster of N processes on\n"
                    "127.0.0.1 (default: the CPU count; 1: dask's synchronous scheduler in\n"
                    "this process); --scheduler ADDRESS uses a running cluster (its workers\n"
                    "must be able to import damper_hil; data are shipped with the tasks).",
        epilog="examples:\n"
               f"  {PROG} fleet-example batch --dampers 12\n"
               f"  {PROG} fleet batch --out batch_out --workers 2\n"
               f"  {PROG} fleet batch --out batch_out --diagnose --scheduler "
               "tcp://127.0.0.1:8786")
    fleet.add_argument("data_dir", metavar="DATA_DIR", type=Path,
                       help="one subfolder per damper")
    fleet.add_argument("--out", metavar="OUT", type=Path, required=True,
                       help="output folder (created; an existing one is resumed)")
    fleet.add_argument("--diagnose", action="store_true",
                       help="also diagnose each damper (docs/diagnose.md; about a minute "
                            "per damper on the short protocol, several on the paper's)")
    fleet.add_argument("--effects", metavar="NAMES", default=None,
                       help="with --diagnose: comma-separated subset of the candidates "
                            "(default: all nine)")
    fleet.add_argument("--retry-errors", action="store_true",
                       help="run the dampers that ended in error in an earlier run of OUT "
                            "again (default: keep their rows)")
    add_engine_options(fleet)
    fleet.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.outputs import Outputs
    from damper_hil.engine import open_engine
    from damper_hil.fleet.inputs import find_dampers
    from damper_hil.fleet.runner import run_fleet
    from damper_hil.fleet.summary import write_summary

    effects = parse_effects(args.effects)
    find_dampers(args.data_dir)  # a wrong DATA_DIR fails before a cluster starts

    # the tables and the summary are one set: checked before any damper runs, renamed into
    # place together at the end (each damper's own files are written as it finishes)
    try:
        with Outputs(say=say) as outputs:
            with open_engine(args.scheduler, args.workers) as engine:
                result = run_fleet(args.data_dir, args.out, engine, diagnose=args.diagnose,
                                   effects=effects, retry_errors=args.retry_errors, say=say,
                                   outputs=outputs)
            write_summary(result, args.out, outputs)
    except KeyboardInterrupt:
        say(f"{PROG} fleet: interrupted; the finished dampers are in {args.out}: run the "
            "same command again to go on")
        raise
    ok = sum(r.get("status") == "ok" for r in result.rows)
    flagged = sorted(i for i, fl in result.flags.items() if fl)
    print(f"{ok} of {len(result.rows)} dampers finished, "
          f"{len(result.rows) - ok} in error, {len(flagged)} flagged"
          f"{': ' + ', '.join(flagged) if flagged else ''} ({result.wall_s:.1f} s)")
    return 0
