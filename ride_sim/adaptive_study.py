"""The adaptive-damper ride study (docs/model.md §6): passive sport, passive comfort and
the skyhook controller on the figure-10 road, several seeds (``damper-hil ride-study
--figure adaptive``).  Beside :mod:`ride_sim.study`, whose settings
(:mod:`ride_sim.study_setup`), roads and metrics (:mod:`ride_sim.study_runs`) it uses; it
alone needs the closed-loop session (:mod:`ride_sim.session`)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from damper_emulator.errors import UserError
from ride_sim.study import Progress, StudyResult, quiet
from ride_sim.study_runs import check_random_road, random_road_input, seed_summary
from ride_sim.study_setup import StudySettings, band_at_speed, default_model

#: Cases of :func:`adaptive_study`, in order, and their labels.
ADAPTIVE_CASES = ("sport", "comfort", "skyhook")
ADAPTIVE_LABELS = {"sport": "passive sport (c = 1)", "comfort": "passive comfort (c = 0)",
                   "skyhook": "skyhook"}
#: The metrics the adaptive study reports (SI: m, m/s², N).
ADAPTIVE_KEYS = ("sws_rms", "accel_w_rms", "dtl_rms")
#: Valve commands of the passive cases.
_PASSIVE_COMMAND = {"sport": 1.0, "comfort": 0.0}


def _ratio_stats(values: Sequence[float]) -> dict[str, float]:
    x = np.asarray(values, dtype=float)
    return {"mean": float(x.mean()), "std": float(x.std(ddof=1)) if x.size > 1 else 0.0,
            "min": float(x.min()), "max": float(x.max())}


def adaptive_study(settings: StudySettings, skyhook, *, model=None,
                   progress: Progress = quiet, keep_traces: bool = True) -> StudyResult:
    """The adaptive damper on ``road.length_m`` of random road at ``road.speed_m_s``,
    ``road.seeds`` seeds: passive sport, passive comfort and skyhook (:data:`ADAPTIVE_CASES`).

    Parameters
    ----------
    settings : StudySettings
    skyhook : ride_sim.skyhook.SkyhookParams
        The controller (``config/skyhook.yaml``); its rate is rounded to a whole number of
        samples (the update rate used is in the document).
    model : DamperModel, optional
        The damper, with a ``damper.adaptive`` group (default ``config/sport.yaml``).

    Returns
    -------
    StudyResult
        ``doc[case]``: every :data:`OUTPUT_KEYS` mean, ``spread`` (std, min, max over
        seeds), ``per_seed``; ``doc["ratio_to_sport"][case][key]`` per-seed ratios to
        passive sport (mean, std, min, max).  Traces of seed 0 (the three rides and the
        skyhook commands) for the plots.
    """
    from ride_sim.dampers import CompressiblePlugin
    from ride_sim.session import semi_active_run
    from ride_sim.skyhook import resolve_rates, skyhook_command

    started = time.perf_counter()
    road, car, dt = settings.road, settings.car, settings.dt_s
    speed = road.speed_m_s
    band = band_at_speed(road, speed)
    check_random_road(road, speed, dt)
    model = default_model() if model is None else model
    if not model.adaptive:
        raise UserError(f"damper '{model.cfg.damper.name}' has no bypass "
                         "(damper.adaptive group): the valve command has no effect")
    rates = resolve_rates(skyhook, model)
    period = max(1, int(round(1.0 / (skyhook.rate_hz * dt))))

    def skyhook_law(body_velocity: float, damper_velocity: float) -> float:
        return skyhook_command(body_velocity, damper_velocity, skyhook.c_sky_ns_m, rates,
                               skyhook.deadband_m_s)

    per_seed: dict[str, list] = {c: [] for c in ADAPTIVE_CASES}
    faults = {c: 0 for c in ADAPTIVE_CASES}
    command_stats: list[dict[str, float]] = []
    traces: dict[str, Any] = {}
    for seed in range(road.seeds):
        heights, n_lead, n_eval = random_road_input(road, speed, seed, dt, band)
        progress(f"adaptive, seed {seed + 1}/{road.seeds}: {road.length_m:g} m at {speed:g} "
                 f"m/s ({n_lead + n_eval} steps) x {len(ADAPTIVE_CASES)} cases")
        for case in ADAPTIVE_CASES:
            if case == "skyhook":
                damper = CompressiblePlugin(model, name="skyhook")
                law, every = skyhook_law, period
            else:
                command = _PASSIVE_COMMAND[case]
                damper = CompressiblePlugin(model, name=case, valve_command=command)
                law, every = (lambda vb, vd, c=command: c), n_lead + n_eval
            out = semi_active_run(car, heights, n_lead, dt, damper, law, every)
            per_seed[case].append(out.metrics)
            faults[case] |= out.result.fault_bits
            if case == "skyhook":
                ev = slice(n_lead, n_lead + n_eval)
                c, ce = out.command[ev], out.effective_command[ev]
                command_stats.append({"mean": float(c.mean()),
                                      "effective_mean": float(ce.mean()),
                                      "fraction_comfort": float(np.mean(c == 0.0)),
                                      "fraction_sport": float(np.mean(c == 1.0))})
            if keep_traces and seed == 0:
                traces[case] = out
                traces["window"] = (n_lead, n_lead + n_eval)
    doc: dict[str, Any] = {
        "figure": "adaptive",
        "title": f"adaptive damper: {road.length_m:g} m of random road (G = {road.roughness:g}, "
                 f"p = {road.waviness:g}) at {speed:g} m/s, {road.seeds} seeds",
        "units": {"sws": "m", "accel": "m/s^2", "dtl": "N", "rates": "N s/m (damper side)"},
        "settings": settings.as_dict(),
        "band_cycles_per_m": list(band),
        "cases": list(ADAPTIVE_CASES),
        "labels": dict(ADAPTIVE_LABELS),
        "damper": {"name": model.cfg.damper.name,
                   "adaptive": dataclasses.asdict(model.cfg.damper.adaptive)},
        "controller": {**dataclasses.asdict(skyhook), "rates_ns_m": rates._asdict(),
                       "update_period_samples": period,
                       "update_rate_hz": 1.0 / (period * dt)},
        "coupling": "every case through ride_sim.session.semi_active_run: damper sampled "
                    "once per step, force and valve command held (zero-order hold)",
    }
    for case in ADAPTIVE_CASES:
        doc[case] = seed_summary(per_seed[case], None)
        doc[case]["fault_bits"] = faults[case]
        if case in _PASSIVE_COMMAND:
            doc[case]["valve_command"] = _PASSIVE_COMMAND[case]
    doc["skyhook"]["valve_command"] = {
        k: _ratio_stats([m[k] for m in command_stats]) for k in command_stats[0]}
    doc["ratio_to_sport"] = {
        case: {key: _ratio_stats([a[key] / b[key] for a, b in
                                  zip(per_seed[case], per_seed["sport"])])
               for key in ADAPTIVE_KEYS}
        for case in ADAPTIVE_CASES if case != "sport"}
    doc["elapsed_s"] = round(time.perf_counter() - started, 3)
    return StudyResult(doc, traces)


def adaptive_table(doc: Mapping[str, Any]) -> str:
    """Plain-text table of an :func:`adaptive_study` document: per case the mean ± std over
    seeds of the three r.m.s. metrics and the mean per-seed ratio to passive sport."""
    head = (f"{'case':<24}{'SWS rms [mm]':>16}{'accel Wk rms [m/s2]':>22}{'DTL rms [kN]':>16}"
            f"{'ratios to sport (SWS / Wk / DTL)':>36}")
    lines = [head]
    for case in doc["cases"]:
        e = doc[case]
        cells = []
        for key, scale, fmt in (("sws_rms", 1e3, ".2f"), ("accel_w_rms", 1.0, ".3f"),
                                ("dtl_rms", 1e-3, ".3f")):
            cells.append(f"{e[key] * scale:{fmt}} ± {e['spread'][key]['std'] * scale:{fmt}}")
        r = doc.get("ratio_to_sport", {}).get(case)
        ratio = " / ".join(f"{r[k]['mean']:.3f}" for k in ADAPTIVE_KEYS) if r else "1"
        lines.append(f"{doc['labels'][case]:<24}{cells[0]:>16}{cells[1]:>22}{cells[2]:>16}"
                     f"{ratio:>36}")
    return "\n".join(lines)


