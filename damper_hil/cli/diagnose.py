"""``damper-hil diagnose``."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from damper_hil.cli.common import (
    PROG,
    CliError,
    Formatter,
    add_columns_options,
    add_rig_option,
    check_unique_names,
    columns_of,
    json_text,
    load_model,
    parse_effects,
    positive_int,
    read_data,
    say,
)


def add_parser(sub) -> None:
    diag = sub.add_parser(
        "diagnose", formatter_class=Formatter,
        help="close the loop on measured data: find the effect the identified model lacks",
        description="Trace the identified model's residual to the effects it lacks.  The\n"
                    "paper's parameters are re-identified jointly with each candidate effect\n"
                    "(friction, thermal, cavitation, valve dynamics, compliance, end stops,\n"
                    "air entrainment, position-dependent damping, gas-spring heat transfer,\n"
                    "inertia)\n"
                    "on the identification files (--quasi-static, --chirp), simulated whole;\n"
                    "each is scored by the r.m.s. reduction on the held-out files (--validate)\n"
                    "and penalised for its parameters (BIC with the residual's effective\n"
                    "sample size).  Forward selection adds the best significant effect and\n"
                    "tests the rest on top while structure remains.  family 'none': the\n"
                    "refitted paper's model is within the floor (0.5 % of the force r.m.s. or\n"
                    "3x the noise) or\n"
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
                           "gas_heat_transfer, inertia")
    diag.add_argument("--jobs", metavar="N", type=positive_int, default=None,
                      help="fit the candidates in N processes (default: the CPU count, at "
                           "most 4)")
    diag.add_argument("--series", metavar="DATA.csv", type=Path, nargs="+", default=None,
                      help="every data file once, in the order the dyno recorded them (what "
                           "moves over the series is weighed in this order; default: the "
                           "files' own time columns where they are one clock, else the "
                           "quasi-static, chirp and held-out files as given)")
    add_columns_options(diag)
    add_rig_option(diag)
    diag.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from damper_emulator.outputs import Outputs

    started = time.perf_counter()
    effects = parse_effects(args.effects)
    check_unique_names([*args.quasi_static, *args.chirp, *args.validate])
    # the outputs are checked now, and written as one set once the diagnosis is done
    inputs = [args.params, *args.quasi_static, *args.chirp, *args.validate,
              *([args.rig] if args.rig else [])]
    with Outputs(say=say, inputs=inputs) as outputs:
        json_at = outputs.file(args.json)
        report_at = outputs.folder(args.report) if args.report is not None else None
        result = _diagnose(args, effects, json_at, report_at)
    width = max(len("file"), *(len(n) for n in result.rms_before))
    print(f"diagnosis: {result.family}" + "".join(
        f"{' +' if k else ''} ({s.candidate.effect}, held-out r.m.s. -{100 * s.score:.1f} %)"
        for k, s in enumerate(result.steps)))
    found = result.discovered
    if found is not None and found.features:
        print(f"discovered{'' if found.significant else ' (not significant)'}: "
              f"{found.expression} (held-out r.m.s. {-100 * found.held_out_gain:+.1f} %, "
              f"family hint {found.family_hint})")
    print(f"{'file':<{width}}  {'role':>8}  {'before [N]':>10}  {'after [N]':>10}")
    for r in result.records:
        print(f"{r.name:<{width}}  {'held out' if r.held_out else 'fit':>8}  "
              f"{result.rms_before[r.name]:>10.2f}  {result.rms_after[r.name]:>10.2f}")
    print(f"finished in {time.perf_counter() - started:.1f} s", file=sys.stderr)
    return 0


def _diagnose(args: argparse.Namespace, effects: list[str] | None, json_at: Path,
              report_at: Path | None):
    """The diagnosis, its JSON written at ``json_at`` and its report in ``report_at``;
    returns the result."""
    import os

    from damper_emulator.diagnose.selection import check_series, diagnose

    model, params_file = load_model(args.params)
    if model.cfg.damper.extensions is not None:
        raise CliError(f"{params_file}: already holds damper.extensions "
                       f"({', '.join(model.cfg.damper.extensions.active())}); diagnose needs "
                       "the identified model without them")
    columns = columns_of(args)
    fit = read_data([*args.quasi_static, *args.chirp], args.rig, columns)
    held = read_data(args.validate, args.rig, columns)
    # by file name, as the records are named
    series = [p.name for p in args.series] if args.series else None
    check_series(series, [d.name for d in (*fit, *held)])
    say(f"diagnosing {params_file}: fit on {', '.join(d.name for d in fit)}, held out "
        f"{', '.join(d.name for d in held)}")
    jobs = args.jobs if args.jobs is not None else min(os.cpu_count() or 1, 4)
    result = diagnose(model, fit, held, effects, jobs=jobs,
                      n_quasi_static=len(args.quasi_static), progress=say, series=series)
    doc = {"params_file": params_file, **result.to_json()}
    if report_at is not None:
        from damper_emulator.diagnose.report import write_report

        files = write_report(result, report_at, params_file)
        doc["report_dir"] = str(args.report)
        doc["report_files"] = [p.name for p in files]
    json_at.write_text(json_text(doc), encoding="utf-8")
    return result

