"""``damper-hil ride-study``."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from damper_emulator.errors import one_line
from damper_hil.cli.common import (
    PROG,
    CliError,
    Formatter,
    json_text,
    positive_float,
    positive_int,
    say,
    schema_type,
)
from ride_sim.params import AMPLITUDE_METHODS, BAND_SCALINGS, RoadParams


def add_parser(sub) -> None:
    ride = sub.add_parser(
        "ride-study", formatter_class=Formatter,
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
               f"  {PROG} ride-study --figure 10 --json fig10.json --report fig10\n"
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
    road = {f.name: f for f in dataclasses.fields(RoadParams)}
    ride.add_argument("--seeds", metavar="N", type=schema_type(road["seeds"], "--seeds"),
                      default=None,
                      help=f"[10, 11, adaptive] road seeds 0..N-1, the same for every "
                           f"damper (default: road.seeds, {RoadParams.seeds})")
    ride.add_argument("--length", metavar="M", default=None,
                      type=schema_type(road["length_m"], "--length"),
                      help=f"[10, 11, adaptive] {road['length_m'].metadata['doc']} "
                           f"(default: road.length_m, {RoadParams.length_m:g})")
    sweep = " ".join(f"{v:g}" for v in RoadParams.sweep_speeds_m_s)
    ride.add_argument("--speed", metavar="V", type=positive_float, nargs="+", default=None,
                      help=f"speed [m/s]: [10, adaptive] one value (default: road.speed_m_s, "
                           f"{RoadParams.speed_m_s:g}), [13] one value (default: "
                           f"road.pothole_speed_m_s, {RoadParams.pothole_speed_m_s:g}), [11] "
                           f"the sweep's speeds (default: road.sweep_speeds_m_s, {sweep})")
    ride.add_argument("--band", metavar=("NMIN", "NMAX"), type=positive_float, nargs=2,
                      default=None,
                      help="[10, 11, adaptive] synthesised road band [cycles/m] (default: "
                           "road.band_cycles_per_m, "
                           + " ".join(f"{v:g}" for v in RoadParams.band_cycles_per_m)
                           + ", the band the paper's figure 10 implies)")
    ride.add_argument("--band-scaling", choices=BAND_SCALINGS, default=None,
                      help="[11] keep the band fixed in Hz as at 20 m/s (temporal) or in "
                           f"cycles/m (spatial) (default: road.band_scaling, "
                           f"{RoadParams.band_scaling})")
    ride.add_argument("--amplitudes", choices=AMPLITUDE_METHODS, default=None,
                      help="[10, 11, adaptive] road synthesis: exact spectrum with random "
                           "phases (deterministic) or random amplitudes too (default: "
                           f"road.amplitudes, {RoadParams.amplitudes})")
    ride.add_argument("--workers", metavar="N", type=positive_int, default=None,
                      help="[11] worker processes (default: all cores)")
    ride.add_argument("--report", "--out", metavar="DIR", dest="report", type=Path,
                      default=None,
                      help="also write the figures (PNG) into DIR: [10] ride_sws_2s.png, "
                           "ride_psd.png, ride_band_sensitivity.png; [11] "
                           "ride_speed_sweep.png; [13] ride_pothole.png; [adaptive] "
                           "ride_adaptive_bars.png, ride_adaptive_history.png")
    ride.add_argument("--skyhook", metavar="SKYHOOK.yaml", type=Path, default=None,
                      help="[adaptive] skyhook params file (default: config/skyhook.yaml)")
    ride.set_defaults(handler=run)
    ride.error = lambda message: ride.exit(  # type: ignore[method-assign]
        2, f"{ride.prog}: error: {one_line(message)}\n")  # one line, no usage block


def run(args: argparse.Namespace) -> int:
    fig = int(args.figure) if args.figure.isdigit() else args.figure
    if args.band is not None and not args.band[0] < args.band[1]:
        raise CliError(f"--band {args.band[0]:g} {args.band[1]:g}: NMIN must be below NMAX")
    if args.speed is not None and fig != 11 and len(args.speed) != 1:
        raise CliError(f"--speed takes one value for --figure {fig} (a list only for 11)")
    for dest in _RIDE_IGNORED[fig]:
        if getattr(args, dest) is not None:
            print(f"note: --{dest.replace('_', '-')} does not apply to --figure {fig}; "
                  "ignored", file=sys.stderr)
    from damper_emulator.outputs import Outputs
    from ride_sim import adaptive_study, study, study_setup, study_tables
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
    settings = study_setup.StudySettings.from_config(cfg, **overrides)
    if fig == "adaptive":
        from ride_sim.skyhook import load_skyhook

        skyhook = load_skyhook(args.skyhook)

    # the outputs are checked now, and written as one set once the study is done
    with Outputs(say=say, inputs=[args.config, args.skyhook]) as outputs:
        json_at = outputs.file(args.json)
        report = outputs.folder(args.report) if args.report is not None else None
        if fig == 10:
            result = study.figure10(settings, progress=say)
        elif fig == 11:
            result = study.figure11(settings, workers=args.workers, progress=say)
        elif fig == "adaptive":
            result = adaptive_study.adaptive_study(settings, skyhook, progress=say)
        else:
            result = study.figure13(settings, progress=say)
        doc = result.doc
        if report is not None:
            doc["report_dir"] = str(args.report)
            doc["report_files"] = [p.name for p in _plots(fig, report, result, settings)]
        json_at.write_text(json_text(doc), encoding="utf-8")
    print(doc["title"])
    if fig == 11:
        print(study_tables.sweep_table(doc))
        for key in ("crossing_linear_nonlinear_m_s", "crossing_linear_14speed_m_s"):
            if key in doc:
                print(f"{key}: {', '.join(f'{v:.1f}' for v in doc[key]) or 'none'} "
                      f"(paper: near {doc['paper_crossing_m_s']:g} m/s)")
    elif fig == "adaptive":
        print(adaptive_study.adaptive_table(doc))
    else:
        print(study_tables.comparison_table(doc))
        claim = doc.get("claim")
        if claim:
            print(f"claim (hysteretic vs 14-speed, {claim['seeds']} seeds): r.m.s. DTL "
                  f"{100 * claim['dtl_rms_reduction']:.1f} % lower (paper ~6 %: "
                  f"{claim['verdict']['dtl_rms']}), peak DTL "
                  f"{100 * claim['dtl_peak_reduction']:.1f} % lower (paper ~10 %: "
                  f"{claim['verdict']['dtl_peak_abs']})")
    print(f"finished in {doc['elapsed_s']:.1f} s", file=sys.stderr)
    return 0
#: ride-study options that do not apply to a figure: figure → option dests
_RIDE_IGNORED = {13: ("seeds", "length", "band", "band_scaling", "amplitudes", "workers",
                      "skyhook"),
                 10: ("band_scaling", "workers", "skyhook"), 11: ("skyhook",),
                 "adaptive": ("band_scaling", "workers")}


def _plots(fig, report: Path, result, settings) -> list[Path]:
    """The figure's plots, written into ``report``."""
    from ride_sim import plots

    doc = result.doc
    if fig == 10:
        return [plots.plot_sws_history(report / "ride_sws_2s.png", result),
                plots.plot_psds(report / "ride_psd.png", result, settings),
                plots.plot_band_sensitivity(report / "ride_band_sensitivity.png", settings)]
    if fig == 11:
        return [plots.plot_speed_sweep(report / "ride_speed_sweep.png", doc, settings)]
    if fig == "adaptive":
        return [plots.plot_adaptive_bars(report / "ride_adaptive_bars.png", doc),
                plots.plot_adaptive_history(report / "ride_adaptive_history.png", result)]
    return [plots.plot_pothole(report / "ride_pothole.png", result)]
