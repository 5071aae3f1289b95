"""``damper-hil tune``."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from damper_hil.cli.common import PROG, Formatter, add_engine_options, say, schema_type

#: the settings ``tune`` takes as options (the others from --settings only)
OPTIONS = ("designs", "refine_rounds", "refine_designs", "road_classes", "speed_m_s",
           "length_m", "seed", "chunk", "bump_travel_m", "rebound_travel_m")


def option_of(name: str) -> str:
    """The option that sets the setting ``name`` (``speed_m_s`` → ``--speed``)."""
    for unit in ("_m_s", "_m"):
        if name.endswith(unit):
            name = name[: -len(unit)]
            break
    return "--" + name.replace("_", "-")


def add_parser(sub) -> None:
    from ride_sim.params import TuneSettings

    tune = sub.add_parser(
        "tune", formatter_class=Formatter,
        help="virtual damper tuning: valve designs on the quarter car, Pareto front, on Dask",
        description="Choose valve settings in simulation (docs/tune.md).  Design variables:\n"
                    "per direction the blow-off preload and spring rate, the leak and the\n"
                    "port restriction (eqs 8-10), as factors of the base damper's values\n"
                    "within bounds (--settings, default x0.5..x2), optionally the adaptive\n"
                    "bypass diameters.  Objectives (minimised, mean over ISO 8608 random\n"
                    "roads): Wk body acceleration r.m.s., dynamic tyre load r.m.s., SWS\n"
                    "r.m.s.; constraint: peak SWS within the travel on every road and the\n"
                    "pothole.  Search: scrambled Sobol designs, then refinement rounds\n"
                    "around the Pareto front; chunks of designs are Dask tasks run by the\n"
                    "many-design kernel.\n\n"
                    "Writes OUT/pareto.json and pareto.csv (the front: objectives and a\n"
                    "params file per design), OUT/chosen_{balanced,comfort,road_holding}.yaml\n"
                    "(loadable by emulate, dyno, ride-study), designs.csv (every design),\n"
                    "pareto.png, fourteen_speed.png, sensitivity.png and summary.md (with a\n"
                    "sensitivity ranking: which valve constant moves which objective).",
        epilog="examples:\n"
               f"  {PROG} tune --params config/sport.yaml --out tune_out --designs 1000\n"
               f"  {PROG} tune --params base.yaml --settings config/tune.yaml --out t "
               "--scheduler tcp://127.0.0.1:8786")
    tune.add_argument("--params", metavar="BASE.yaml", type=Path, default=None,
                      help="the base damper (default: config/sport.yaml)")
    tune.add_argument("--out", metavar="OUT", type=Path, required=True,
                      help="output folder (created; an earlier run's is replaced as a whole)")
    tune.add_argument("--settings", metavar="TUNE.yaml", type=Path, default=None,
                      help="the 'tune' group: settings and bounds (default: the "
                           "values of config/tune.yaml; docs/parameters.md); options "
                           "given here override it")
    tune.add_argument("--quarter-car", metavar="CAR.yaml", type=Path, default=None,
                      help="quarter car, time step and pothole (default: "
                           "config/quarter_car.yaml)")
    tune.add_argument("--bypass", action="store_true", default=None,
                      help="also tune the adaptive bypass diameters")
    fields = {f.name: f for f in dataclasses.fields(TuneSettings)}
    for name in OPTIONS:
        f = fields[name]
        option = option_of(name)
        kind = str if f.metadata["rule"] == "text" else schema_type(f, option)
        tune.add_argument(option, dest=f"tune_{name}", metavar="N" if f.type == "int"
                          else "VALUE", type=kind, default=None,
                          help=f"{f.metadata['doc']} (default: {f.default})")
    add_engine_options(tune)
    tune.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.outputs import Outputs
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config
    from damper_emulator.schema import read_yaml
    from damper_hil.engine import open_engine
    from damper_hil.tune.report import write_results
    from damper_hil.tune.runner import run_tune
    from ride_sim.params import load_ride_config
    from ride_sim.tuning import check_base, roads, spec_from_mapping

    base = load_config(args.params)
    base_file = str(args.params if args.params is not None else DEFAULT_PARAMS_FILE)
    where = str(args.settings) if args.settings is not None else "options"
    doc = read_yaml(args.settings) if args.settings is not None else None
    overrides = {name: getattr(args, f"tune_{name}") for name in OPTIONS}
    overrides["bypass"] = args.bypass
    spec = spec_from_mapping(doc, where, **overrides)
    check_base(base, spec, base_file)
    ride = load_ride_config(args.quarter_car)
    roads(spec.settings, ride.road, ride.simulation.step_s)  # a bad road fails here, once

    # OUT is checked now, and written as a whole once the search is done (an earlier
    # run's folder is replaced, not mixed with this one's)
    with Outputs(say=say, inputs=[args.params, args.settings, args.quarter_car]) as outputs:
        out = outputs.folder(args.out)
        with open_engine(args.scheduler, args.workers) as engine:
            result = run_tune(base, spec, ride.quarter_car, ride.road, ride.simulation.step_s,
                              engine, say=say)
        doc_out = write_results(result, base, base_file, out)
    c = doc_out["chosen"]["balanced"]
    b = doc_out["baseline"]["objectives"]
    print(f"{doc_out['evaluated']} designs in {doc_out['wall_s']:.1f} s, "
          f"{len(doc_out['designs'])} on the Pareto front; balanced {c['id']}: "
          + ", ".join(f"{k} {100 * (v / b[k] - 1):+.1f} %"
                      for k, v in c["objectives"].items()))
    return 0
