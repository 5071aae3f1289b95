"""``damper-hil validate``."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from damper_hil.cli.common import (
    PROG,
    Formatter,
    add_columns_options,
    add_rig_option,
    check_unique_names,
    columns_of,
    json_text,
    load_model,
    read_data,
    say,
)


def add_parser(sub) -> None:
    validate = sub.add_parser(
        "validate", formatter_class=Formatter,
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
                               "displacement [m], force [N], optional velocity [m/s]; or "
                               "a bag's /damper/force); base names must differ")
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
    add_columns_options(validate)
    add_rig_option(validate)
    validate.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from damper_emulator import validation, validation_report
    from damper_emulator.acquisition.chain import chain_json
    from damper_emulator.outputs import Outputs

    paths: list[Path] = args.data
    check_unique_names(paths)
    json_path: Path = args.json if args.json is not None else (
        (args.report if args.report is not None else Path(".")) / "validation.json")
    # the outputs are checked now, and written as one set once every file is validated
    with Outputs(say=say, inputs=[args.params, *paths, *([args.rig] if args.rig else [])]
                 ) as outputs:
        report: Path | None = (outputs.folder(args.report) if args.report is not None
                               else None)
        json_at = outputs.file(json_path)
        model, params_file = load_model(args.params)
        columns = columns_of(args)
        datasets = read_data(paths, args.rig, columns)  # a bad file fails before work
        results: dict[str, Any] = {}
        n = len(datasets)
        for k, data in enumerate(datasets, 1):
            say(f"[{k}/{n}] validating {data.name} ({len(data)} samples, "
                f"{data.duration_s:.3g} s) ...")
            results[data.name] = validation.validate_file(model, data)
        json_at.write_text(json_text({
            "params_file": params_file,
            "files": {name: validation.json_summary(r) for name, r in results.items()},
            "acquisition": chain_json(datasets[0].acquisition if datasets else None),
        }), encoding="utf-8")
        if report is not None:
            label = f"{args.params.name}, damper '{model.cfg.damper.name}'"
            for name, r in results.items():
                validation_report.plot_validation(
                    report / f"validate_{validation.report_stem(name)}.png", r,
                    title=f"{name} vs compressible model ({label}): "
                          f"{validation_report.rms_caption(r)}")
            validation_report.plot_relative_rms_summary(
                report / "validation_summary.png", results,
                title=f"Validation of {args.params.name}: relative r.m.s. force error per "
                      "file (label: r.m.s. in N)")
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
