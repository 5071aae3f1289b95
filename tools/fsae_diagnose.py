#!/usr/bin/env python3
"""``damper-hil diagnose`` on the FSAE TTX25 dyno data, heat-gun runs included.

Two cases, each through the ordinary command line:

* **3_3_24_24**, the setting with a cold run and two heat-gun runs: ``identify`` with the
  cold 10-cycle run (``t1_3_3_24_24_s5_n10_100psi``, 25–28 °C) as the chirp and the slow run
  of setting 1_1_18_18 at the same charge (``t1_1_1_18_18_s1_n10_100psi``, same damper body,
  gas and seals) as the quasi-static test (a 1 Hz run is no quasi-static test: its viscous
  force swamps the gas spring); then ``diagnose`` fitted on the cold run and the first
  heat-gun run (``t1_…_with_heat_gun``, 28 → 52 °C) and scored on the second
  (``t2_…_with_heat_gun``, 51 → 70 °C: hotter than anything fitted).
* **2_2_12_12**, the setting whose rebound force fades most with temperature (−17 %) and that
  has only one run, heat-gun: the run is cut in three equal stretches of time; ``identify``
  with the first (the coolest) as the chirp and the same slow run as above, ``diagnose``
  fitted on the first two stretches and scored on the third (the hottest).

Writes ``docs/measured/fsae_diagnose/<setting>/`` (the diagnose report: report.md, overlay
plots, ranking), the identified parameters beside it (``params_<setting>.yaml``) and
``docs/measured/fsae_diagnose/summary.json``.  The commands read the vendor's files as
they are, through their folder's column map (``fsae_identify.link_runs``); the stretches
of the 2_2_12_12 run are written to a temporary directory and deleted afterwards: nothing
from the files is written into the repository except derived figures and figures of merit.

Usage: ``.venv/bin/python tools/fsae_diagnose.py [--data DIR] [--keep DIR]``
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from fsae_identify import ALPHA_BOUNDS, FIXED, link_runs, run_cli

from damper_emulator.dyno.fsae import export_fsae_csv, read_fsae_ttx25
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.dyno.measured_bag import read_measured
from damper_hil.warm import ensure_warmed

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured" / "fsae_ttx25"
OUT = REPO / "docs" / "measured" / "fsae_diagnose"
BASE = REPO / "config" / "fsae_ttx25_base.yaml"
#: as tools/fsae_identify.py: G held (one speed cannot determine it), α fitted
IDENTIFY_OPTIONS = (*(x for fix in FIXED for x in ("--fix", fix)), "--fit-alpha",
                    "--alpha-bounds", *ALPHA_BOUNDS)


def cut(data: MeasuredData, lo: float, hi: float, name: str) -> MeasuredData:
    """The stretch of ``data`` between the fractions ``lo`` and ``hi`` of its duration, its
    time starting at 0."""
    t = data.time
    t0, t1 = t[0] + lo * (t[-1] - t[0]), t[0] + hi * (t[-1] - t[0])
    k = (t >= t0) & (t <= t1)
    return MeasuredData(time=t[k] - t[k][0], displacement=data.displacement[k],
                        force=data.force[k],
                        velocity=None if data.velocity is None else data.velocity[k],
                        temperature=None if data.temperature is None else data.temperature[k],
                        name=name, path=name)


def temperature_range(data: MeasuredData) -> list[float]:
    return [round(float(np.min(data.temperature)), 1), round(float(np.max(data.temperature)), 1)]


def case(work: Path, setting: str, ident: list[Path], fit: list[Path], held: list[Path],
         temps: dict[str, list[float]]) -> dict:
    """identify on ``ident`` (quasi-static, chirp), diagnose fitted on ``fit`` and scored on
    ``held``."""
    # beside the report folder, which names it relative to itself (diagnose replaces the
    # report folder whole, and refuses one that holds an input)
    params = OUT / f"params_{setting}.yaml"
    started = time.perf_counter()
    run_cli(["identify", "--quasi-static", str(ident[0]), "--chirp", str(ident[1]),
             "--base", str(BASE), *IDENTIFY_OPTIONS, "--out", str(params),
             "--json", str(work / f"identify_{setting}.json")])
    t_ident = time.perf_counter() - started
    report = OUT / setting
    out_json = work / f"diagnose_{setting}.json"
    started = time.perf_counter()
    run_cli(["diagnose", "--params", str(params), "--quasi-static", str(fit[0]),
             "--chirp", *(str(p) for p in fit[1:]), "--validate", *(str(p) for p in held),
             "--json", str(out_json), "--report", str(report)])
    t_diag = time.perf_counter() - started
    doc = json.loads(out_json.read_text())
    doc.pop("params_file", None)
    doc.pop("report_dir", None)
    ident_doc = json.loads((work / f"identify_{setting}.json").read_text())
    return {"identified_on": [p.name for p in ident], "fit": [p.name for p in fit],
            "held_out": [p.name for p in held], "temperatures_c": temps,
            "identify_s": round(t_ident, 1), "diagnose_s": round(t_diag, 1),
            "alpha_per_pa": (ident_doc.get("alpha_fit") or {}).get("alpha_per_pa"),
            "diagnosis": doc}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--keep", type=Path, default=None,
                    help="link the runs here and keep them (default: a temporary dir)")
    ap.add_argument("--only", choices=("3_3_24_24", "2_2_12_12"), default=None,
                    help="run one case; the other's entry of summary.json is kept")
    args = ap.parse_args()
    # the kernels an install loads (a diagnosis can follow a fresh compile's last bits)
    ensure_warmed()
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        old = OUT / "summary.json"
        summary = json.loads(old.read_text()) if args.only and old.exists() else {}
        # 3_3_24_24: cold run, two heat-gun runs
        slow_stem = "t1_1_1_18_18_s1_n10_100psi"
        (slow,) = link_runs(args.data, [slow_stem], work).values()
        if args.only in (None, "3_3_24_24"):
            paths = link_runs(args.data, ["t1_3_3_24_24_s5_n10_100psi",
                                          "t1_3_3_24_24_s5_n100_100psi_with_heat_gun",
                                          "t2_3_3_24_24_s5_n100_100psi_with_heat_gun"], work)
            cold, hg1, hg2 = paths.values()
            temps = {p.name: temperature_range(read_measured(p)) for p in paths.values()}
            summary["3_3_24_24"] = case(work, "3_3_24_24", [slow, cold], [cold, hg1], [hg2],
                                        temps)
        # 2_2_12_12: one heat-gun run in three stretches
        stem = "t2_2_2_12_12_s5_n100_100psi_with_heat_gun"
        if args.only in (None, "2_2_12_12"):
            run = read_fsae_ttx25(args.data / f"{stem}.csv.gz")
            parts = [cut(run, i / 3.0, (i + 1) / 3.0, f"{stem}_part{i + 1}.csv")
                     for i in range(3)]
            ppaths = [export_fsae_csv(p, work / "stretches") for p in parts]
            temps = {p.name: temperature_range(p) for p in parts}
            summary["2_2_12_12"] = case(work, "2_2_12_12", [slow, ppaths[0]], ppaths[:2],
                                        [ppaths[2]], temps)
    (OUT / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"wrote {OUT / 'summary.json'}", file=sys.stderr)
    for setting, s in summary.items():
        if args.only not in (None, setting):
            continue
        d = s["diagnosis"]
        print(f"{setting}: {d['family']} ({d['effect']}), held-out "
              + ", ".join(f"{n} {d['rms_before'][n]:.1f} → {d['rms_after'][n]:.1f} N"
                          for n in d["held_out"]))


if __name__ == "__main__":
    main()
