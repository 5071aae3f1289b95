"""``damper-hil fleet-example``."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from damper_hil.cli.common import (
    PROG,
    CliError,
    Formatter,
    non_negative_int,
    positive_int,
    say_wrote,
    schema_type,
)


def scatter_option(name: str) -> str:
    """The option that sets the :class:`Scatter` field ``name``."""
    return f"--scatter-{name.replace('_', '-')}"


def add_parser(sub) -> None:
    from dataclasses import fields

    from damper_hil.fleet.scatter import DEFECTS, Scatter

    ex = sub.add_parser(
        "fleet-example", formatter_class=Formatter,
        help="write a virtual production batch of dampers' dyno tests, for fleet",
        description="Write one folder per unit, as fleet reads them: the nominal damper\n"
                    "(--params) with unit-to-unit scatter, run over the virtual dyno's\n"
                    "identification and validation protocol with 4 N of force noise and a\n"
                    "smooth friction (a model-form difference from the emulator's model).\n"
                    "Seeded defects: "
                    + "; ".join(f"unit {k}: {name}" for k, (name, _) in DEFECTS.items())
                    + ".\nDATA_DIR/truth.json lists every unit's true parameters and defect.",
        epilog=f"example:\n  {PROG} fleet-example batch --dampers 12 && "
               f"{PROG} fleet batch --out batch_out")
    ex.add_argument("out", metavar="DATA_DIR", type=Path,
                    help="folder to write (must be empty or not exist)")
    ex.add_argument("--dampers", metavar="N", type=positive_int, default=12,
                    help="units in the batch")
    ex.add_argument("--seed", metavar="S", type=non_negative_int, default=0,
                    help="random seed of the scatter and the noise")
    ex.add_argument("--short", action="store_true",
                    help="a short protocol (12 s chirp, one quasi-static cycle) instead of "
                         "the paper's: quicker to identify and diagnose")
    ex.add_argument("--params", metavar="PARAMS.yaml", type=Path, default=None,
                    help="the nominal damper (default: config/sport.yaml)")
    for f in fields(Scatter):
        option = scatter_option(f.name)
        ex.add_argument(option, dest=f"scatter_{f.name}", metavar="SIGMA",
                        type=schema_type(f, option), default=f.default,
                        help=f"{f.metadata['doc']} (default: %(default)s)")
    ex.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from dataclasses import fields

    from damper_emulator.params import load_config
    from damper_hil.fleet.example import write_example
    from damper_hil.fleet.scatter import Scatter

    if args.out.exists() and (not args.out.is_dir() or any(args.out.iterdir())):
        raise CliError(f"{args.out}: exists and is not an empty folder")
    nominal = load_config(args.params)
    scatter = Scatter(**{f.name: getattr(args, f"scatter_{f.name}") for f in fields(Scatter)})
    write_example(args.out, nominal, args.dampers, args.seed, args.short, scatter,
                  say=lambda m: print(m, file=sys.stderr, flush=True))
    say_wrote(args.out / "truth.json")
    return 0
