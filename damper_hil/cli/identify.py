"""``damper-hil identify``."""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from damper_hil.cli.common import (
    CliError,
    Formatter,
    add_columns_options,
    add_rig_option,
    columns_of,
    json_text,
    read_data,
    say,
)

#: identify warns when a quasi-static file moves faster than this [m/s] (99th percentile):
#: twice the FSAE slow run's 26 mm/s, twelve times the paper's 4 mm/s
QUASI_STATIC_WARN_SPEED_M_S = 0.05


def add_parser(sub) -> None:
    ident = sub.add_parser(
        "identify", formatter_class=Formatter,
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
    ident.add_argument("--chirp-friction-factor", metavar="F", type=float, default=1.0,
                       help="the friction at the chirp's speeds (taken out of the force "
                            "before the valve fits, and the parameter file's friction) is F "
                            "times the quasi-static fit's; 1 is the paper's one friction. A "
                            "seal with less friction at a few mm/s than at speed otherwise "
                            "moves both valves' pressure drops by the difference")
    ident.add_argument("--no-compressibility-correction", action="store_true",
                       help="use the rigid-oil valve flow |v|(A_pt − A_rod) as the paper does")
    add_columns_options(ident)
    add_rig_option(ident)
    ident.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.outputs import Outputs

    started = time.perf_counter()
    factor = args.chirp_friction_factor
    if not (math.isfinite(factor) and factor >= 0):
        raise CliError(f"--chirp-friction-factor {factor!r}: must be a finite number ≥ 0")
    # the outputs are checked, and written as one set once the work is done
    with Outputs(say=say, inputs=[*args.quasi_static, *args.chirp, args.base,
                                     *([args.rig] if args.rig else [])]) as outputs:
        params_at = outputs.file(args.out)
        json_path = args.json or args.out.with_suffix(".json")
        json_at = outputs.file(json_path)
        report_at = outputs.folder(args.report) if args.report is not None else None
        doc, result = _identify(args, started, params_at, report_at)
        json_at.write_text(json_text(doc), encoding="utf-8")
    print(f"identified in {doc['elapsed_s']:.1f} s: quasi-static r.m.s. "
          f"{result.quasi_static.rms:.2f} N, rebound {result.rebound.rms:.2f} N, "
          f"compression {result.compression.rms:.2f} N", file=sys.stderr)
    return 0


def _identify(args: argparse.Namespace, started: float, params_at: Path,
              report_at: Path | None):
    """The identification, its parameter file written at ``params_at`` and its report in
    ``report_at``; returns the JSON document and the result."""
    from damper_emulator.acquisition.chain import chain_json
    from damper_emulator.identify.pipeline import identify
    from damper_emulator.params import DEFAULT_PARAMS_FILE, load_config, save_config

    base = load_config(args.base)
    fixed = _fixed_valve_parameters(args.fix)
    columns = columns_of(args)
    qs = read_data(args.quasi_static, args.rig, columns)
    chirp = read_data(args.chirp, args.rig, columns)
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
                      alpha_bounds_per_pa=args.alpha_bounds,
                      chirp_friction_factor=args.chirp_friction_factor)
    save_config(result.config, params_at)
    doc = {"params_file": str(args.out),
           "base_params_file": str(args.base or DEFAULT_PARAMS_FILE),
           "quasi_static_file": str(args.quasi_static[0]), "chirp_file": str(args.chirp[0]),
           "quasi_static_files": [str(p) for p in args.quasi_static],
           "chirp_files": [str(p) for p in args.chirp], "fixed": fixed,
           "compressibility_correction": not args.no_compressibility_correction,
           "acquisition": chain_json(qs[0].acquisition),
           **result.as_dict()}
    if report_at is not None:
        from damper_emulator.identify.report import write_report

        write_report(report_at, result)
        doc["report_dir"] = str(args.report)
    doc["elapsed_s"] = round(time.perf_counter() - started, 3)
    return doc, result
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
