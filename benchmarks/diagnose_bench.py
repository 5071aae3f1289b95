#!/usr/bin/env python3
"""Benchmark of ``identify`` + ``diagnose`` on truth data; prints a markdown table.

Every scenario is what a user runs: ``identify`` on the quasi-static and chirp files with
the damper's data sheet as ``--base`` (its geometry, γ, ν, α; its other values only as
starts), then ``diagnose`` on the same files with the validation sines held out.

The data come from the truth simulation (``damper_emulator/diagnose/truth.py``) over the
paper's protocol as the virtual dyno runs it (quasi-static 150 s at 50 Hz, chirp 60 s at
1 kHz, sines 1 Hz/3 Hz at 50 mm and 12 Hz at 5 mm), with 4 N of force noise, a
temperature column (25 → 50 °C over the chirp, sines at 55/65/45 °C) and the model-form
differences of ``truth.REALISTIC_FINE``: smooth friction (tanh, 5 mm/s) in place of eq 4's
switch, 5 µm of displacement noise, and every truth integrated on 4× shorter sub-steps
than the data sheet's (a damper is continuous: the model's own sub-step is part of what
it leaves).  Scenarios:

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
  library's effects at 150 Hz, each with and without the chain given;
* a test series (``/paper`` or ``/speeds``: the paper's programme, or the quasi-static
  test and a peak-velocity series identified together with a random road held out,
  ``truth.SPEED_PROGRAMME``), each kind of :data:`SERIES` in two sizes on the three
  dampers in turn: mains hum, a drifting zero behind a flat thermometer, a gain, a gas
  leak, an oil that warms from file to file with and without its column; and a humming,
  drifting rig behind a 150 Hz filter;
* inertia of 1.5, 5 and 10 kg (the speed programme);
* end stops outside the library's form at both ends (:func:`stop_force`: elastomer,
  exponential, hydraulic), on both programmes;
* every library effect with a second one it dominates (``a>b``; ``~weak``: the weaker
  parameters of :data:`WEAK_EFFECTS`);
* a library effect beside an effect of :data:`OUTSIDE` (:data:`MIXED`): a LuGre friction
  and a 6 kg mass, a cavity and a damping zone; both families named, by the library's
  effects or the discovered term, and nothing else.

Targets: every single effect named with the held-out r.m.s. within 2×
the noise afterwards, and through a filter named with the held-out r.m.s. at least
halved; ``none`` on all three dampers, raw and through a filter with and
without the chain given; ``inertia`` for the mass (held-out within 2× the noise);
``position_dependent`` for the zone, ``friction`` for the seal and ``end_stop`` for the
stops, each halving the held-out r.m.s. at least; both effects named in the pairs; for a
series, the family expected (``none`` for the rig's) with the rig's findings and the
drifting parameter; in every case no effect named of a family the truth lacks; each
diagnosis ≤ 3 minutes.  Each row also says whether the held-out
r.m.s. after is within 3× the noise the truth added (:data:`NOISE_N`; not the diagnosis's
own noise levels, shown beside its floor: the refitted model's, which a large smooth
residual raises, and that of what is left after).

Usage: ``python benchmarks/diagnose_bench.py [--jobs N] [--only NAME ...]``
(``NAME`` a scenario label as printed, e.g. ``sport:valve_lag``,
``sport:lugre_friction+valve_lag`` or ``touring:none@100Hz+rig``, or a label's start
followed by ``*``; run in the order given).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from machine import cpu_name

from damper_emulator.diagnose.selection import diagnose
from damper_emulator.diagnose.truth import (
    EXAMPLE_EFFECTS,
    REALISTIC_FINE,
    SPEED_PROGRAMME,
    Protocol,
    example_config,
    simulate_session,
)
from damper_emulator.diagnose.truth_series import RigFaults, Series, gas_leak
from damper_emulator.identify.pipeline import identify
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import EXTENSION_FAMILIES, load_config
from damper_hil.warm import ensure_warmed

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
OUTSIDE = {"inertia": "inertia", "zone": "position_dependent", "seal": "friction",
           **{f"stops_{form}": "end_stop" for form in ("elastomer", "exponential",
                                                       "hydraulic")}}
#: the damper of an outside effect, where not the data sheet's: the seal's gas volume is
#: small enough for the gas pressure to change with the stroke (±25 % over ±50 mm; the
#: sport damper's ±7 % would make the seal a Coulomb friction the paper's model has)
OUTSIDE_BASE = {"seal": {"gas_volume_static_m3": 4.0e-5}}
#: the load-cell filters [Hz] of the scenarios through a rig without an effect (one per
#: damper, in order), and the one of the library's effects
NONE_FILTERS_HZ = (200.0, 100.0, 300.0)
EFFECT_FILTER_HZ = 150.0
#: the test programmes: the paper's (quasi-static + chirp, the sines held out) and the
#: speed programme (quasi-static + a peak-velocity series of sines, a random road held
#: out: truth.SPEED_PROGRAMME)
PROGRAMMES = ("paper", "speeds")
#: the masses of the inertia series, one per damper [kg]
INERTIA_SIZES_KG = (1.5, 5.0, 10.0)
#: end stops outside the library's form, at both ends (rebound, compression) [m] for
#: each programme: the paper's sines reach ±50 mm, the speed series ±25 mm
STOP_POSITIONS = {"paper": (0.035, -0.038), "speeds": (0.018, -0.02)}
STOP_FORMS = ("elastomer", "exponential", "hydraulic")
#: the hydraulic stop's cup closes over this length [m] (its orifice's area falls
#: linearly, to nothing there; the programmes go at most 15 mm into a stop) ...
TAPER_LENGTH_M = 0.025
#: ... and the taper is taken no further than this [m] (a bound on the force)
TAPER_STOP_M = 0.02
#: every library effect with a second one it dominates (``~weak``: the second effect's
#: weaker parameters, :data:`WEAK_EFFECTS`)
DOMINANT_PAIRS = (("cavitation", "lugre_friction"), ("end_stops", "viscosity_temperature"),
                  ("valve_lag", "gas_heat_transfer"), ("series_compliance", "bypass_groove"),
                  ("viscosity_temperature", "air_entrainment"),
                  ("bypass_groove", "lugre_friction"),
                  ("air_entrainment", "gas_heat_transfer"),
                  ("gas_heat_transfer", "lugre_friction~weak"),
                  ("lugre_friction", "valve_lag~weak"))
#: a library effect beside an effect of :data:`OUTSIDE` (``a+b``)
MIXED = (("lugre_friction", "inertia"), ("cavitation", "zone"))
#: weaker parameters of some library effects, for a pair's dominated second
WEAK_EFFECTS = {"lugre_friction": {"coulomb_n": 43.7, "static_n": 55.0,
                                   "stribeck_velocity_m_s": 0.01,
                                   "bristle_stiffness_n_m": 1.5e5},
                "valve_lag": {"time_constant_s": 5e-4}}


@dataclass(frozen=True)
class Scenario:
    """One benchmark case: the damper, the library's effects or an effect outside it in
    the truth, the load-cell filter (0: raw) and whether the chain is given, the test
    series' rig faults and damper drift (:data:`SERIES`), and the test programme."""

    label: str
    damper: str
    effects: tuple[str, ...] = ()
    fc: float = 0.0
    given: bool = False
    series: str | None = None
    programme: str = "paper"
    #: the mass of an ``inertia`` truth [kg]
    mass_kg: float = INERTIA_KG

    @property
    def protocol(self) -> Protocol:
        return SPEED_PROGRAMME if self.programme == "speeds" else Protocol()


def _hum(amplitude_n: float):
    """Mains hum: 50 Hz of ``amplitude_n`` and a third of it at 150 Hz."""
    return lambda sheet: Series(faults=RigFaults(
        lines=((50.0, amplitude_n), (150.0, amplitude_n / 3.0))))


def _zero(rate_n_s: float):
    """A load cell zeroed 5 N off before the series, drifting ``rate_n_s``; the
    thermocouple reads a flat 25 °C (the case that was named thermal)."""
    return lambda sheet: Series(faults=RigFaults(zero_offset_n=5.0,
                                                 zero_drift_n_per_s=rate_n_s),
                                oil_temperatures_c=(25.0,) * 20)


def _gain(gain: float):
    return lambda sheet: Series(faults=RigFaults(gain=gain))


def _leak(fraction: float):
    return lambda sheet: Series(changes=gas_leak(sheet.damper.gas_pressure_static_pa,
                                                 fraction))


def _warm(step_k: float, column: bool):
    """The oil ``step_k`` warmer with every file, from 25 °C, the thermocouple's column
    in the files or not."""
    return lambda sheet: Series(oil_temperatures_c=tuple(25.0 + step_k * k
                                                         for k in range(20)),
                                temperature_column=column)


#: the series scenarios: their Series (of the data sheet), the family expected, the
#: measurement kinds expected and the drifting parameter expected
SERIES = {
    "hum3": (_hum(3.0), "none", {"interference"}, None),
    "hum10": (_hum(10.0), "none", {"interference"}, None),
    "zero0.1": (_zero(0.1), "none", {"zero_offset"}, None),
    "zero0.5": (_zero(0.5), "none", {"zero_offset"}, None),
    "gain0.97": (_gain(0.97), "none", set(), None),
    "gain1.05": (_gain(1.05), "none", set(), None),
    "leak3": (_leak(0.03), "gas_spring", set(), "gas_pressure_static_pa"),
    "leak8": (_leak(0.08), "gas_spring", set(), "gas_pressure_static_pa"),
    "warm5": (_warm(5.0, False), "thermal", set(), "valve_pressure_scale"),
    "warm10T": (_warm(10.0, True), "thermal", set(), None),
}


def scenarios() -> list[Scenario]:
    """Every benchmark case, in order (the labels are what ``--only`` takes)."""
    out = [Scenario(f"{d}:none", d) for d in DAMPERS]
    out += [Scenario(f"sport:{e}", "sport", (e,)) for e in EXAMPLE_EFFECTS]
    out += [Scenario(f"{d}:{e}", d, (e,)) for d, e in zip(DAMPERS[1:], OTHER_DAMPER_EFFECTS)]
    out += [Scenario(f"sport:{e}", "sport", (e,)) for e in ("inertia", "zone", "seal")]
    out += [Scenario(f"sport:{a}+{b}", "sport", (a, b)) for a, b in PAIRS]
    for d, fc in zip(DAMPERS, NONE_FILTERS_HZ):
        out += [Scenario(f"{d}:none@{fc:g}Hz{'+rig' if given else ''}", d, (), fc, given)
                for given in (False, True)]
    for given in (False, True):
        out += [Scenario(f"sport:{e}@{EFFECT_FILTER_HZ:g}Hz{'+rig' if given else ''}",
                         "sport", (e,), EFFECT_FILTER_HZ, given) for e in EXAMPLE_EFFECTS]
    # the test series: every kind in two sizes, on the three dampers in turn, the
    # programmes alternating
    for k, name in enumerate(SERIES):
        d, prog = DAMPERS[k % len(DAMPERS)], PROGRAMMES[k % len(PROGRAMMES)]
        out.append(Scenario(f"{d}:{name}/{prog}", d, series=name, programme=prog))
    out.append(Scenario("sport:hum3+zero0.1@150Hz/paper", "sport", (), EFFECT_FILTER_HZ,
                        series="hum3+zero0.1"))
    for d, m in zip(DAMPERS, INERTIA_SIZES_KG):
        out.append(Scenario(f"{d}:inertia{m:g}kg/speeds", d, ("inertia",),
                            programme="speeds", mass_kg=m))
    for k, form in enumerate(STOP_FORMS):
        for j, prog in enumerate(PROGRAMMES):
            d = DAMPERS[(k + j) % len(DAMPERS)]
            out.append(Scenario(f"{d}:stops_{form}/{prog}", d, (f"stops_{form}",),
                                programme=prog))
    out += [Scenario(f"sport:{a}>{b}", "sport", (a, b)) for a, b in DOMINANT_PAIRS]
    out += [Scenario(f"sport:{a}+{b}", "sport", (a, b)) for a, b in MIXED]
    return out


def stop_force(form: str, programme: str):
    """``f(t, x, v)`` of end stops outside the library's form, at both ends of the
    programme's stroke (:data:`STOP_POSITIONS`; the compression stop 1.5 times as stiff):
    an elastomer (``k₁ δ + k₃ δ³``, 20 % hysteresis with the direction), an exponential
    stiffening (``a (e^(δ/δ₀) − 1)``), a hydraulic stop in a tapered cup (an orifice's
    ``c ẋ|ẋ|``, its area closing as ``1 − δ/δ_t``, so ``c₀ / (1 − δ/δ_t)²``; and a soft
    spring)."""
    x_r, x_c = STOP_POSITIONS[programme]

    def one(d, v_in):
        """The force [N] of one stop at penetration ``d`` ≥ 0 and speed into it."""
        if form == "elastomer":
            return (5e4 * d + 5e7 * d ** 3) * (1.0 + 0.2 * np.tanh(v_in / 0.01))
        if form == "exponential":
            return 300.0 * (np.exp(d / 0.015) - 1.0)
        taper = 1.0 - np.minimum(d, TAPER_STOP_M) / TAPER_LENGTH_M
        return 1.5e3 * v_in * np.abs(v_in) / taper ** 2 + 5e4 * d

    def force(t, x, v):
        dr, dc = np.maximum(x - x_r, 0.0), np.maximum(x_c - x, 0.0)
        return np.where(dr > 0, one(dr, v), 0.0) - np.where(dc > 0, 1.5 * one(dc, -v), 0.0)
    return force


def outside_force(name: str, cfg, mass_kg: float = INERTIA_KG, programme: str = "paper"):
    """``f(t, x, v)`` of an effect outside the library (:data:`OUTSIDE`) on ``cfg``."""
    from damper_emulator.model.compressible import simulate

    if name.startswith("stops_"):
        return stop_force(name[len("stops_"):], programme)
    if name == "inertia":
        return lambda t, x, v: mass_kg * np.gradient(v, t)
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


def series_of(name: str | None, sheet):
    """The Series of a scenario (``a+b``: both's rig faults)."""
    if name is None:
        return None
    if "+" in name:
        parts = [SERIES[n][0](sheet) for n in name.split("+")]
        faults = parts[0].faults
        for p in parts[1:]:
            faults = dataclasses.replace(
                faults, lines=faults.lines + p.faults.lines,
                zero_offset_n=faults.zero_offset_n + p.faults.zero_offset_n,
                zero_drift_n_per_s=faults.zero_drift_n_per_s + p.faults.zero_drift_n_per_s)
        return dataclasses.replace(parts[-1], faults=faults)
    return SERIES[name][0](sheet)


def session(sc: Scenario, seed: int):
    """``(data sheet config, files)`` of one scenario."""
    sheet = load_config(ROOT / "config" / f"{sc.damper}.yaml")
    effects = sc.effects
    if len(effects) == 1 and effects[0] in OUTSIDE_BASE:
        sheet = dataclasses.replace(sheet, damper=dataclasses.replace(
            sheet.damper, **OUTSIDE_BASE[effects[0]]))
    extra = None
    library = tuple(e for e in effects if e not in OUTSIDE)
    outside = [e for e in effects if e in OUTSIDE]
    if outside:
        truth = truth_config(library, sheet) if library else example_config(None, sheet)
        extra = outside_force(outside[0], truth, sc.mass_kg, sc.programme)
    else:
        truth = truth_config(effects, sheet)
    series = series_of(sc.series, sheet)
    if sc.series is not None and sc.series.startswith("warm"):
        truth = example_config(("viscosity_temperature",), sheet)
    form = REALISTIC_FINE
    rig = rig_of(sc.fc)
    data = simulate_session(truth, sc.protocol, NOISE_N, seed, temperature=True,
                            extra_force=extra, form=form, rig=rig, series=series)
    files = list(data.values())
    if sc.given:
        files = [dataclasses.replace(f, acquisition=rig) for f in files]
    return sheet, files


def truth_config(effects: tuple[str, ...], sheet):
    """The truth of the library's ``effects`` on ``sheet`` (``name~weak``: the weaker
    parameters of :data:`WEAK_EFFECTS`)."""
    from damper_emulator.diagnose.truth import example_base_changes
    from damper_emulator.params import with_extensions

    names = [e.split("~")[0] for e in effects]
    params = {e.split("~")[0]: (WEAK_EFFECTS[e.split("~")[0]] if e.endswith("~weak")
                                else EXAMPLE_EFFECTS[e]["params"]) for e in effects}
    return with_extensions(sheet, params, example_base_changes(names))


def expected(sc: Scenario) -> tuple[set[str], set[str], str | None]:
    """The families, the measurement kinds and the drifting parameter expected."""
    if sc.series is not None:
        names = sc.series.split("+")
        fams = {SERIES[n][1] for n in names}
        kinds = set().union(*(SERIES[n][2] for n in names))
        return fams, kinds, SERIES[names[0]][3]
    effects = sc.effects
    if not effects:
        return {"none"}, set(), None
    return ({OUTSIDE[e] if e in OUTSIDE else EXTENSION_FAMILIES[e.split("~")[0]]
             for e in effects}, set(), None)


def _pooled(rms: dict, counts: dict) -> float:
    """The r.m.s. over all samples of the files ``counts`` (as the diagnosis pools)."""
    n = sum(counts.values())
    return float(np.sqrt(sum(rms[k] ** 2 * c for k, c in counts.items()) / n))


def chosen(every: list[Scenario], only: list[str] | None) -> list[Scenario]:
    """The scenarios ``--only`` names, in the order it names them (a label's start with
    ``*``: its scenarios in their order), each once; every scenario without ``--only``.
    Exits with one line on a name that matches none."""
    if only is None:
        return every
    out: list[Scenario] = []
    for o in only:
        found = [s for s in every
                 if s.label == o or (o.endswith("*") and s.label.startswith(o[:-1]))]
        if not found:
            sys.exit(f"no scenario {o!r}; one of: " + ", ".join(s.label for s in every))
        out += [s for s in found if s not in out]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=min(os.cpu_count() or 1, 4))
    ap.add_argument("--only", nargs="+", default=None,
                    help="scenario labels, or a label's start followed by '*', run in "
                         "the order given")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", metavar="DIR", type=Path, default=None,
                    help="write each scenario's diagnose JSON there (LABEL.json)")
    ap.add_argument("--perturb", type=float, default=0.0, metavar="REL",
                    help="scale every file's force by 1 + REL (e.g. 1e-12): every fit's "
                         "arithmetic moves as on another machine or build; a robust "
                         "answer stays")
    args = ap.parse_args()

    todo = chosen(scenarios(), args.only)
    # the kernels an install loads (a diagnosis can follow a fresh compile's last bits)
    ensure_warmed()
    print("# Identify + diagnose on the truth scenarios\n")
    print(f"machine: {cpu_name()}, {os.cpu_count()} CPUs; diagnose with {args.jobs} "
          f"process(es); force noise {NOISE_N} N"
          + (f"; every force scaled by 1 + {args.perturb:g}" if args.perturb else ""))
    print()
    print("| scenario | expected | diagnosed (effects added) | ok | held-out r.m.s. [N]: "
          "identified → refit → after (floor; noise level: refit, after) | ≤ 3σ | rig's findings; "
          "drift | main effect fitted | identify + diagnose [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    walls, oks, within = [], [], []
    for sc in todo:
        sheet, files = session(sc, args.seed)
        if args.perturb:
            files = [dataclasses.replace(f, force=f.force * (1.0 + args.perturb))
                     for f in files]
        n_fit = sc.protocol.n_fit
        t0 = time.perf_counter()
        cfg = identify(files[0], files[1:n_fit], sheet).config
        t1 = time.perf_counter()
        d = diagnose(DamperModel(cfg), files[:n_fit], files[n_fit:], jobs=args.jobs,
                     progress=lambda m: print(m, file=sys.stderr, flush=True))
        wall = time.perf_counter() - t0
        walls.append(time.perf_counter() - t1)
        doc = d.to_json()
        if args.json is not None:
            args.json.mkdir(parents=True, exist_ok=True)
            name = re.sub(r"[^A-Za-z0-9_.+-]", "_", sc.label)
            (args.json / f"{name}.json").write_text(json.dumps(doc, indent=1, default=str))
        counts = {r.name: r.counted for r in d.records if r.name in d.held_out}
        b, a = _pooled(d.rms_before, counts), _pooled(d.rms_after, counts)
        r = _pooled(d.refit.rms_held_out, counts) if d.refit else math.nan
        found = [s.candidate.family for s in d.steps]
        kinds = {m["kind"] for m in doc["measurement"]}
        drifting = {x["parameter"] for x in doc["drift"]}
        fams, exp_kinds, exp_drift = expected(sc)
        effects = sc.effects
        outside = len(effects) == 1 and effects[0] in OUTSIDE
        if sc.series is not None:
            ok = (d.family in fams and exp_kinds <= kinds
                  and (exp_drift is None or exp_drift in drifting))
        elif effects and (not outside or effects[0] == "inertia") and len(effects) == 1:
            ok = d.family in fams and a <= (0.5 * b if sc.fc else 2.0 * NOISE_N)
        elif outside:
            ok = d.family in fams and a <= 0.5 * b
        elif any(e in OUTSIDE for e in effects):  # the library's family and the term's
            term = d.term
            ok = fams == {*found, *([term.family_hint] if term is not None else [])}
        elif len(effects) == 2:
            ok = fams <= set(found)
        else:
            ok = d.family in fams
        # an effect named that the truth lacks is a wrong answer, beside a right one too
        ok = ok and set(found) <= fams
        oks.append(ok)
        near = a <= 3.0 * NOISE_N
        if d.family != "none":
            within.append(near)
        c = d.chosen or d.closest
        fitted = (f"{c.candidate.effect}: " + ", ".join(f"{k} {v:.4g}" for k, v in
                                                        c.values.items())) if c else "–"
        found_term = d.discovered
        if found_term is not None and found_term.features:
            fitted += (f"; discovered{'' if found_term.significant else ' (n.s.)'}: "
                       f"{found_term.expression}")
        acq = doc["acquisition"]
        if acq["source"] == "estimated":
            fitted += f"; delay {1e3 * acq['force_delay_s']:.3f} ms"
        shown = d.family + (f" ({', '.join(s.candidate.effect for s in d.steps)})"
                            if d.steps else "")
        rig = ", ".join(sorted(kinds - {"delay", "filter", "skew"})) or "–"
        rig += "; " + (", ".join(sorted(drifting)) or "–")
        print(f"| {sc.label} | {' + '.join(sorted(fams))} | {shown} | {'✓' if ok else '✗'} | "
              f"{b:.1f} → {r:.1f} → {a:.1f} ({d.floor_n:.1f}; {d.noise_n:.1f}, "
              f"{d.noise_after_n:.1f}) | {'✓' if near else '✗'} | "
              f"{rig} | {fitted} | {t1 - t0:.0f} + {wall - (t1 - t0):.0f} |", flush=True)
    print(f"\n{sum(oks)} of {len(oks)} right; held-out within 3× the noise ({3 * NOISE_N:g} N) in "
          f"{sum(within)} of {len(within)} with an effect or a drift; diagnose wall time "
          f"median {np.median(walls):.0f} s, max {max(walls):.0f} s (target ≤ 180 s)")


if __name__ == "__main__":
    main()
