#!/usr/bin/env python3
"""Benchmark of ``identify`` + ``diagnose`` on truth data; prints a markdown table.

Every scenario is what a user runs: ``identify`` on the quasi-static and chirp files with
the damper's data sheet as ``--base`` (its geometry, γ, ν, α; its other values only as
starts), then ``diagnose`` on the same files with the validation sines held out.

The data come from the truth simulation (``damper_emulator/diagnose/truth.py``) over the
paper's protocol as the virtual dyno runs it (quasi-static 150 s at 50 Hz, chirp 60 s at
1 kHz, sines 1 Hz/3 Hz at 50 mm and 12 Hz at 5 mm), with 4 N of force noise, a
temperature column (25 → 50 °C over the chirp, sines at 55/65/45 °C) and the model-form
differences of ``truth.REALISTIC``: smooth friction (tanh, 5 mm/s) in place of eq 4's
switch and 5 µm of displacement noise; the noise-only truths are also integrated on 4×
shorter sub-steps (``REALISTIC_FINE``).  Scenarios:

* ``none``: no extra effect, on the sport, touring and van dampers (config/*.yaml);
* one effect of each family (``EXAMPLE_EFFECTS``) on the sport damper, and one on each
  other damper (a valve lag on the touring damper, end stops on the van's);
* three effects outside the library, found by the term discovery: ``inertia``, a 6 kg
  mass between load cell and damper; ``zone``, damping over a Gaussian part of the stroke
  (``600 N·s/m exp(−(x − 8 mm)²/(2 (6 mm)²)) ẋ``); ``seal``, a seal pressed by the gas
  (``10⁻⁴ m² · P_com tanh(ẋ / 2 mm/s)``, ``P_com`` the truth's own gas pressure, a sign
  sharper than the dictionary's) on the sport damper with a gas volume of 40 cm³, whose
  gas pressure changes by ±25 % over ±50 mm;
* five pairs of effects;
* through a rig (``@N Hz``: the force recorded through a 2nd-order Butterworth load-cell
  filter at N Hz into a 12-bit converter of ±10 kN; ``+rig``: the chain given to both
  commands, else estimated): no effect on the three dampers at 100–300 Hz, and the
  library's effects at 150 Hz, each with and without the chain given.

Targets: every single effect named with the held-out r.m.s. within 2×
the noise afterwards, and through a filter named with the held-out r.m.s. at least
halved; ``none`` on all three dampers, raw and through a filter with and
without the chain given; ``inertia`` for the mass (held-out within 2× the noise);
``position_dependent`` for the zone and ``friction`` for the seal, each halving the
held-out r.m.s. at least; both effects named in at least 4 of the 5 pairs; each diagnosis
≤ 3 minutes.

Usage: ``python benchmarks/diagnose_bench.py [--jobs N] [--only NAME ...]``
(``NAME`` a scenario label as printed, e.g. ``sport:valve_lag``,
``sport:lugre_friction+valve_lag`` or ``touring:none@100Hz+rig``).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np
from machine import cpu_name

from damper_emulator.diagnose.selection import diagnose
from damper_emulator.diagnose.truth import (
    EXAMPLE_EFFECTS,
    REALISTIC,
    REALISTIC_FINE,
    Protocol,
    example_config,
    simulate_session,
)
from damper_emulator.identify.pipeline import identify
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import EXTENSION_FAMILIES, load_config

#: the repository (the dampers' files are config/*.yaml there, from any working folder)
ROOT = Path(__file__).resolve().parents[1]
NOISE_N = 4.0
INERTIA_KG = 6.0
DAMPERS = ("sport", "touring", "van")
#: the effect run on each damper other than the sport one (in order)
OTHER_DAMPER_EFFECTS = ("valve_lag", "end_stops")
PAIRS = (("lugre_friction", "valve_lag"), ("end_stops", "series_compliance"),
         ("viscosity_temperature", "bypass_groove"), ("air_entrainment", "lugre_friction"),
         ("cavitation", "valve_lag"))


#: the effects outside the library (the term discovery's): their expected family
OUTSIDE = {"inertia": "inertia", "zone": "position_dependent", "seal": "friction"}
#: the damper of an outside effect, where not the data sheet's: the seal's gas volume is
#: small enough for the gas pressure to change with the stroke (±25 % over ±50 mm; the
#: sport damper's ±7 % would make the seal a Coulomb friction the paper's model has)
OUTSIDE_BASE = {"seal": {"gas_volume_static_m3": 4.0e-5}}
#: the load-cell filters [Hz] of the scenarios through a rig without an effect (one per
#: damper, in order), and the one of the library's effects
NONE_FILTERS_HZ = (200.0, 100.0, 300.0)
EFFECT_FILTER_HZ = 150.0


def scenarios() -> list[tuple[str, str, tuple[str, ...], float, bool]]:
    """``(label, damper, effects, load-cell filter [Hz] (0: raw), chain given)``."""
    out = [(f"{d}:none", d, (), 0.0, False) for d in DAMPERS]
    out += [(f"sport:{e}", "sport", (e,), 0.0, False) for e in EXAMPLE_EFFECTS]
    out += [(f"{d}:{e}", d, (e,), 0.0, False) for d, e in zip(DAMPERS[1:],
                                                             OTHER_DAMPER_EFFECTS)]
    out += [(f"sport:{e}", "sport", (e,), 0.0, False) for e in OUTSIDE]
    out += [(f"sport:{a}+{b}", "sport", (a, b), 0.0, False) for a, b in PAIRS]
    for d, fc in zip(DAMPERS, NONE_FILTERS_HZ):
        out += [(f"{d}:none@{fc:g}Hz{'+rig' if given else ''}", d, (), fc, given)
                for given in (False, True)]
    for given in (False, True):
        out += [(f"sport:{e}@{EFFECT_FILTER_HZ:g}Hz{'+rig' if given else ''}", "sport", (e,),
                 EFFECT_FILTER_HZ, given) for e in EXAMPLE_EFFECTS]
    return out


def outside_force(name: str, cfg):
    """``f(t, x, v)`` of an effect outside the library (:data:`OUTSIDE`) on ``cfg``."""
    from damper_emulator.model.compressible import simulate

    if name == "inertia":
        return lambda t, x, v: INERTIA_KG * np.gradient(v, t)
    if name == "zone":
        return lambda t, x, v: 600.0 * np.exp(-0.5 * ((x - 0.008) / 0.006) ** 2) * v

    def seal(t, x, v):
        # a seal pressed by the gas: its friction grows with the gas pressure (it does
        # not enter the pressures, as eq 4's friction does not)
        p_gas = simulate(DamperModel(cfg), t, x, v).compression_pressure_pa
        return 1e-4 * p_gas * np.tanh(v / 0.002)
    return seal


def rig_of(fc: float):
    """The rig of a filtered scenario (``None`` raw)."""
    from damper_emulator.acquisition.rig import ForceChannel, RigParams

    if fc <= 0.0:
        return None
    return RigParams(force=ForceChannel(filter="butterworth", order=2, cutoff_hz=fc,
                                        adc_bits=12, full_scale_n=10_000.0))


def session(damper: str, effects: tuple[str, ...], seed: int, fc: float = 0.0,
            given: bool = False):
    """``(data sheet config, files)`` of one scenario."""
    import dataclasses

    sheet = load_config(ROOT / "config" / f"{damper}.yaml")
    if len(effects) == 1 and effects[0] in OUTSIDE_BASE:
        sheet = dataclasses.replace(sheet, damper=dataclasses.replace(
            sheet.damper, **OUTSIDE_BASE[effects[0]]))
    extra = None
    if len(effects) == 1 and effects[0] in OUTSIDE:
        truth = example_config(None, sheet)
        extra = outside_force(effects[0], truth)
    else:
        truth = example_config(effects, sheet)
    form = REALISTIC_FINE if not effects else REALISTIC
    rig = rig_of(fc)
    data = simulate_session(truth, Protocol(), NOISE_N, seed, temperature=True,
                            extra_force=extra, form=form, rig=rig)
    files = list(data.values())
    if given:
        files = [dataclasses.replace(f, acquisition=rig) for f in files]
    return sheet, files


def expected(effects: tuple[str, ...]) -> set[str]:
    if not effects:
        return {"none"}
    if len(effects) == 1 and effects[0] in OUTSIDE:
        return {OUTSIDE[effects[0]]}
    return {EXTENSION_FAMILIES[e] for e in effects}


def _pooled(rms: dict, counts: dict) -> float:
    """The r.m.s. over all samples of the files ``counts`` (as the diagnosis pools)."""
    n = sum(counts.values())
    return float(np.sqrt(sum(rms[k] ** 2 * c for k, c in counts.items()) / n))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=min(os.cpu_count() or 1, 4))
    ap.add_argument("--only", nargs="+", default=None, help="scenario labels")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    todo = [s for s in scenarios() if args.only is None or s[0] in args.only]
    if not todo:
        sys.exit("no such scenario; one of: " + ", ".join(s[0] for s in scenarios()))
    print("# Identify + diagnose on the truth scenarios\n")
    print(f"machine: {cpu_name()}, {os.cpu_count()} CPUs; diagnose with {args.jobs} "
          f"process(es); force noise {NOISE_N} N")
    print()
    print("| scenario | expected | diagnosed (effects added) | ok | held-out r.m.s. [N]: "
          "identified → refit → after (floor) | main effect fitted | identify + diagnose "
          "[s] |")
    print("|---|---|---|---|---|---|---|")
    walls, oks = [], []
    for label, damper, effects, fc, given in todo:
        sheet, files = session(damper, effects, args.seed, fc, given)
        t0 = time.perf_counter()
        cfg = identify(files[0], files[1], sheet).config
        t1 = time.perf_counter()
        d = diagnose(DamperModel(cfg), files[:2], files[2:], jobs=args.jobs,
                     progress=lambda m: print(m, file=sys.stderr, flush=True))
        wall = time.perf_counter() - t0
        walls.append(time.perf_counter() - t1)
        counts = {r.name: r.counted for r in d.records if r.name in d.held_out}
        b, a = _pooled(d.rms_before, counts), _pooled(d.rms_after, counts)
        r = _pooled(d.refit.rms_held_out, counts) if d.refit else math.nan
        found = [s.candidate.family for s in d.steps]
        exp = expected(effects)
        outside = len(effects) == 1 and effects[0] in OUTSIDE
        if effects and (not outside or effects[0] == "inertia") and len(effects) == 1:
            ok = d.family in exp and a <= (0.5 * b if fc else 2.0 * NOISE_N)
        elif outside:
            ok = d.family in exp and a <= 0.5 * b
        elif len(effects) == 2:
            ok = exp <= set(found)
        else:
            ok = d.family in exp
        oks.append(ok)
        c = d.chosen or d.closest
        fitted = (f"{c.candidate.effect}: " + ", ".join(f"{k} {v:.4g}" for k, v in
                                                        c.values.items())) if c else "–"
        found_term = d.discovered
        if found_term is not None and found_term.features:
            fitted += (f"; discovered{'' if found_term.significant else ' (n.s.)'}: "
                       f"{found_term.expression}")
        acq = d.to_json()["acquisition"]
        if acq["source"] == "estimated":
            fitted += f"; delay {1e3 * acq['force_delay_s']:.3f} ms"
        shown = d.family + (f" ({', '.join(s.candidate.effect for s in d.steps)})"
                            if d.steps else "")
        print(f"| {label} | {' + '.join(sorted(exp))} | {shown} | {'✓' if ok else '✗'} | "
              f"{b:.1f} → {r:.1f} → {a:.1f} ({d.floor_n:.1f}) | {fitted} | "
              f"{t1 - t0:.0f} + {wall - (t1 - t0):.0f} |", flush=True)
    print(f"\n{sum(oks)} of {len(oks)} right; diagnose wall time median "
          f"{np.median(walls):.0f} s, max {max(walls):.0f} s (target ≤ 180 s)")


if __name__ == "__main__":
    main()
