#!/usr/bin/env python3
"""Benchmark of ``diagnose`` on the paper's protocol; prints markdown tables.

For each scenario the truth simulation (damper_emulator/diagnose/truth.py) makes the
paper's protocol as the virtual dyno runs it (quasi-static 150 s at 50 Hz, chirp 60 s at
1 kHz, sines 1 Hz/3 Hz at 50 mm and 12 Hz at 5 mm, 2 N force noise) with one effect of the
library, none, or one outside it (a 6 kg mass between load cell and damper), and
``diagnose`` fits all nine candidates on the quasi-static + chirp files and scores them on
the sines.  Target (issue 7): a full diagnosis in ≤ 2 minutes.

``--none-seeds N`` also runs N noise-only sessions and reports the best candidate's
held-out r.m.s. reduction on each: the level the significance threshold must clear.

``--identify`` gives ``diagnose`` the parameters ``identify`` finds on the same quasi-static
and chirp files (the base data sheet as its fixed part), as a user would, instead of the
truth's base parameters: the identification then absorbs part of the effect.

Usage: ``python benchmarks/diagnose_bench.py [--jobs N] [--none-seeds N] [--only NAME]
[--identify]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from damper_emulator.diagnose.selection import diagnose
from damper_emulator.identify.pipeline import identify
from damper_emulator.diagnose.truth import (EXAMPLE_EFFECTS, Protocol, example_config,
                                            simulate_session, with_extension)
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import EXTENSION_FAMILIES, load_config

from machine import cpu_name  # noqa: E402  (same folder)

NOISE_N = 2.0
INERTIA_KG = 6.0


def _scenario(name: str, seed: int):
    """``(expected family, base config, session data)``."""
    cfg = load_config()
    if name == "none":
        base = with_extension(cfg, None)
        return "none", base, simulate_session(base, Protocol(), NOISE_N, seed)
    if name == "inertia":
        base = with_extension(cfg, None)
        data = simulate_session(base, Protocol(), NOISE_N, seed,
                                extra_force=lambda t, x, v: INERTIA_KG * np.gradient(v, t))
        return "other", base, data
    base = with_extension(cfg, None, None, EXAMPLE_EFFECTS[name].get("base"))
    data = simulate_session(example_config(name), Protocol(), NOISE_N, seed,
                            temperature=name == "viscosity_temperature")
    return EXTENSION_FAMILIES[name], base, data


def _pooled(rms: dict, names) -> float:
    return float(np.sqrt(np.mean([rms[n] ** 2 for n in names])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=min(os.cpu_count() or 1, 4))
    ap.add_argument("--none-seeds", type=int, default=0)
    ap.add_argument("--only", default=None, help="one scenario (an effect, none, inertia)")
    ap.add_argument("--identify", action="store_true",
                    help="diagnose on top of identify's result from the same files")
    args = ap.parse_args()
    scenarios = ["none", *EXAMPLE_EFFECTS, "inertia"]
    if args.only:
        scenarios = [args.only]
    print(f"machine: {cpu_name()}, {os.cpu_count()} CPUs; diagnose with {args.jobs} "
          f"process(es); {time.strftime('%Y-%m-%d')}")
    # warm-up (numba's on-disk cache)
    _e, base, data = _scenario("none", 99)
    files = list(data.values())
    diagnose(DamperModel(base), files[:2], files[2:3], effects=["valve_lag"])
    print()
    print("| truth | expected | diagnosed | held-out r.m.s. before → after [N] | "
          "score | ΔBIC | fitted | wall [s] |")
    print("|---|---|---|---|---|---|---|---|")
    walls = []
    for name in scenarios:
        expected, base, data = _scenario(name, 1)
        files = list(data.values())
        t0 = time.perf_counter()
        if args.identify:
            base = identify(files[0], files[1], base).config
        d = diagnose(DamperModel(base), files[:2], files[2:], jobs=args.jobs,
                     progress=lambda m: print(m, file=sys.stderr))
        wall = time.perf_counter() - t0
        walls.append(wall)
        b, a = _pooled(d.rms_before, d.held_out), _pooled(d.rms_after, d.held_out)
        c = d.chosen or d.closest or d.ranking[0]
        fitted = ", ".join(f"{k} {v:.4g}" for k, v in c.values.items())
        ok = "✓" if d.family == expected else "✗"
        print(f"| {name} | {expected} | {d.family} {ok} | {b:.1f} → {a:.1f} | "
              f"{c.score:+.3f} | {c.delta_bic:.0f} | {c.candidate.effect}: {fitted} | "
              f"{wall:.1f} |", flush=True)
    print(f"\nwall time per diagnosis: median {np.median(walls):.1f} s, max "
          f"{max(walls):.1f} s (target ≤ 120 s)")
    if args.none_seeds:
        print("\n| noise-only seed | best candidate | its held-out r.m.s. reduction | ΔBIC |")
        print("|---|---|---|---|")
        best_scores = []
        for seed in range(100, 100 + args.none_seeds):
            _e, base, data = _scenario("none", seed)
            files = list(data.values())
            d = diagnose(DamperModel(base), files[:2], files[2:], jobs=args.jobs)
            best = max(d.ranking, key=lambda c: c.score)
            best_scores.append(best.score)
            print(f"| {seed} | {best.candidate.effect} | {100 * best.score:+.2f} % | "
                  f"{best.delta_bic:.0f} |", flush=True)
        print(f"\nlargest: {100 * max(best_scores):+.2f} %")


if __name__ == "__main__":
    main()
