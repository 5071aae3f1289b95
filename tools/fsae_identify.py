#!/usr/bin/env python3
"""Identification and validation of the FSAE TTX25 dyno data with the project's CLI.

Runs ``damper-hil identify`` and ``damper-hil validate`` on valve setting 1_1_18_18 (the
only setting with more than one speed), twice: α from the base file (the paper's procedure)
and α fitted (``--fit-alpha``), and writes

* ``docs/measured/fsae_identification.md`` (the generated tables between the
  ``<!-- results:begin -->`` / ``<!-- results:end -->`` markers; the prose around them is
  kept),
* the identification and validation report figures under ``docs/measured/fsae_identify/``.

The commands read the vendor's files as they are, through the column map of their folder
(:func:`link_runs`: links to them in a temporary directory, beside a ``columns.yaml``):
nothing from them is written into the repository except derived figures.

Usage: ``.venv/bin/python tools/fsae_identify.py [--data DIR] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from damper_emulator.dyno.column_map import write_sidecar
from damper_emulator.dyno.fsae import FLIPPED_FOLDER, column_map, parse_fsae_name
from damper_emulator.params import load_config, save_config
from damper_hil.cli import main as cli

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured" / "fsae_ttx25"
DOC = REPO / "docs" / "measured" / "fsae_identification.md"
FIGURES = REPO / "docs" / "measured" / "fsae_identify"
BASE = REPO / "config" / "fsae_ttx25_base.yaml"
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"

SETTING = "1_1_18_18"
#: (run, role); the quasi-static stand-in, the chirp stand-in and the held-out runs
RUNS = (("t1_1_1_18_18_s1_n10_100psi", "quasi-static"),
        ("t1_1_1_18_18_s6_n10_100psi", "chirp"),
        ("t1_1_1_18_18_s5_n10_50psi", "held out"),
        ("t1_1_1_18_18_s5_n10_150psi", "held out"))
#: the charge the identification runs were made at [psi gauge]
FIT_CHARGE_PSI = 100.0
#: valve parameters the three speeds cannot determine (see the doc)
FIXED = ("smoothing_g=1.5",)
ALPHA_BOUNDS = ("1e-9", "3e-7")


def link_runs(data: Path, stems: list[str], work: Path) -> dict[str, Path]:
    """Each run (a file stem, at the top of ``data`` or in its :data:`FLIPPED_FOLDER`)
    linked into a folder of ``work`` that holds the column map its folder needs (a
    ``columns.yaml`` sidecar: every command then reads the vendor's file as it is).  The
    links are named ``<stem>.csv`` (the reader knows gzip by its first bytes)."""
    linked = {}
    for stem in stems:
        source = data / f"{stem}.csv.gz"
        if not source.is_file():
            source = data / FLIPPED_FOLDER / f"{stem}.csv.gz"
        folder = work / source.parent.name
        folder.mkdir(parents=True, exist_ok=True)
        write_sidecar(folder, column_map(source))
        link = folder / f"{stem}.csv"
        link.unlink(missing_ok=True)
        link.symlink_to(source.resolve())
        linked[stem] = link
    return linked


def run_cli(args: list[str]) -> None:
    print("damper-hil " + " ".join(args), file=sys.stderr, flush=True)
    status = cli(args)
    if status != 0:
        raise SystemExit(f"damper-hil {args[0]} failed with status {status}")


def params_at_charge(params: Path, psi: float, out: Path) -> Path:
    """The identified parameters with the gas pressure scaled to another charge (gauge)."""
    cfg = load_config(params)
    scaled = cfg.replace_damper(gas_pressure_static_pa=cfg.damper.gas_pressure_static_pa
                                * psi / FIT_CHARGE_PSI)
    save_config(scaled, out)
    return out


def collect_figures(report: Path, figures: Path, suffix: str = "") -> None:
    """The PNGs of one command's report folder into ``figures`` (``suffix`` added to the
    validation summary's name): each command replaces its own report folder as a whole,
    so every command writes its own, and the figures are gathered in one place."""
    figures.mkdir(parents=True, exist_ok=True)
    for png in report.glob("*.png"):
        name = (f"validation_summary{suffix}.png" if png.name == "validation_summary.png"
                else png.name)
        shutil.copyfile(png, figures / name)


def identify_and_validate(work: Path, csvs: dict[str, Path], label: str,
                          extra: list[str], figures: Path | None) -> dict:
    params = work / f"params_{label}.yaml"
    qs = [str(csvs[r]) for r, role in RUNS if role == "quasi-static"]
    chirp = [str(csvs[r]) for r, role in RUNS if role == "chirp"]
    args = ["identify", "--quasi-static", *qs, "--chirp", *chirp, "--base", str(BASE),
            "--out", str(params), "--json", str(work / f"identify_{label}.json")]
    for fix in FIXED:
        args += ["--fix", fix]
    report = work / f"report_{label}_identify"
    if figures is not None:
        args += ["--report", str(report)]
    started = time.perf_counter()
    run_cli(args + extra)
    elapsed = time.perf_counter() - started
    if figures is not None:
        collect_figures(report, figures)
    ident = json.loads((work / f"identify_{label}.json").read_text())
    files: dict[str, dict] = {}
    by_charge: dict[float, list[str]] = {}
    for run, _role in RUNS:
        by_charge.setdefault(parse_fsae_name(run).gas_psi, []).append(run)
    for psi, runs in sorted(by_charge.items()):
        p = params_at_charge(params, psi, work / f"params_{label}_{psi:g}psi.yaml")
        out_json = work / f"validate_{label}_{psi:g}.json"
        args = ["validate", "--params", str(p), *(str(csvs[r]) for r in runs),
                "--json", str(out_json)]
        report = work / f"report_{label}_{psi:g}psi"
        if figures is not None:
            args += ["--report", str(report)]
        run_cli(args)
        if figures is not None:
            collect_figures(report, figures, f"_{psi:g}psi")
        files.update(json.loads(out_json.read_text())["files"])
    return {"identify": ident, "validate": files, "elapsed_s": elapsed}


def fmt_rel(r: dict) -> str:
    return f"{r['rms_N']:.1f} N ({100 * r['relative_rms']:.1f} %)"


def tables(results: dict[str, dict], temps: dict[str, float]) -> str:
    base, fitted = results["base_alpha"], results["fitted_alpha"]
    lines = ["| run | role | charge [psi] | body T [°C] | α from base file | α fitted |",
             "|---|---|---|---|---|---|"]
    for run, role in RUNS:
        name = run + ".csv"
        lines.append(f"| {run} | {role} | {parse_fsae_name(run).gas_psi:g} | {temps[run]:.1f} "
                     f"| {fmt_rel(base['validate'][name])} "
                     f"| {fmt_rel(fitted['validate'][name])} |")
    lines.append("")
    lines.append("r.m.s. of simulated − measured force over the whole file (eq 34) and "
                 "relative to the measured r.m.s. (eq 35); the compressible model, "
                 "simulated from the measured displacement and velocity.")
    lines.append("")
    lines.append("| parameter | α from base file | α fitted |")
    lines.append("|---|---|---|")

    def row(label, fn):
        lines.append(f"| {label} | {fn(base['identify'])} | {fn(fitted['identify'])} |")

    def qs(key, scale, unit, digits=3):
        def fn(doc):
            fit = doc["quasi_static_fit"]
            v, s = fit["parameters"][key], fit["std_errors"][key]
            if key in fit.get("at_bound", []):
                return f"{v * scale:.{digits}g} {unit} (at a bound)"
            return f"{v * scale:.{digits}g} ± {s * scale:.2g} {unit}"
        return fn

    row("P_gas,static (100 psi run)", qs("gas_pressure_static_pa", 1e-6, "MPa"))
    row("V_gas,static", qs("gas_volume_static_m3", 1e6, "cm³"))
    row("F_friction", qs("friction_force_n", 1.0, "N"))
    def alpha(d):
        fixed = d["fixed"]["oil_compressibility_per_pa"]
        return f"{(d['alpha_fit'] or {}).get('alpha_per_pa', fixed):.3g}"
    row("α [1/Pa]", alpha)
    for side in ("rebound", "compression"):
        for key in ("k_leak", "k_port", "k_spring", "preload_pa", "smoothing_g"):
            def fn(doc, side=side, key=key):
                fit = doc[f"{side}_fit"]
                v = fit["parameters"][key]
                if key in fit.get("fixed", []):
                    return f"{v:.3g} (held)"
                if key in fit.get("at_bound", []):
                    return f"{v:.3g} (at a bound)"
                rel = fit["relative_std_errors"][key]
                return f"{v:.3g} ± {100 * rel:.0f} %" if rel is not None else f"{v:.3g}"
            row(f"{side} {key}", fn)
    row("valve fit r.m.s. rebound / compression [N]",
        lambda d: f"{d['rebound_fit']['rms_N']:.2f} / {d['compression_fit']['rms_N']:.2f}")
    row("quasi-static fit r.m.s. [N]", lambda d: f"{d['quasi_static_fit']['rms_N']:.2f}")
    lines.append(f"| identification time [s] | {base['elapsed_s']:.1f} | "
                 f"{fitted['elapsed_s']:.1f} |")
    if fitted["identify"].get("alpha_fit"):
        a = fitted["identify"]["alpha_fit"]
        tried = ", ".join(f"{t['alpha_per_pa']:.3g} → "
                          + (f"{t['chirp_rms_N']:.1f} N" if t["chirp_rms_N"] is not None
                             else "invalid valve")
                          for t in a["tried"])
        lines += ["", f"α search ({len(a['tried'])} identifications, bounds "
                  f"{a['bounds_per_pa'][0]:.2g}…{a['bounds_per_pa'][1]:.2g} 1/Pa"
                  f"{', optimum AT A BOUND' if a['at_bound'] else ''}): {tried}."]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep the linked runs and results in this directory")
    args = parser.parse_args(argv)
    if not (args.data / "pressure_testing").is_dir():
        print(f"fsae_identify: no data under {args.data}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        from damper_emulator.dyno.measured_bag import read_measured

        csvs = link_runs(args.data, [run for run, _role in RUNS], work)
        temps = {run: float(np.mean(read_measured(path).temperature))
                 for run, path in csvs.items()}
        FIGURES.mkdir(parents=True, exist_ok=True)
        for old in FIGURES.glob("*.png"):
            old.unlink()
        results = {
            "base_alpha": identify_and_validate(work, csvs, "base", [], None),
            "fitted_alpha": identify_and_validate(
                work, csvs, "alpha", ["--fit-alpha", "--alpha-bounds", *ALPHA_BOUNDS],
                FIGURES),
        }
        text = DOC.read_text() if DOC.exists() else f"{BEGIN}\n{END}\n"
        head, _, rest = text.partition(BEGIN)
        _, _, tail = rest.partition(END)
        generated = ("<!-- generated by tools/fsae_identify.py; do not edit by hand -->\n\n"
                     + tables(results, temps))
        DOC.write_text(f"{head}{BEGIN}\n{generated}\n{END}{tail}")
        print(f"wrote {DOC}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
