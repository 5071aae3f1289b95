"""Quarter-car ride studies: Simms & Crolla (SAE 2002-01-0319) figures 10, 11 and 13, and
the adaptive-damper study (docs/model.md §6: :mod:`ride_sim.adaptive_study`).

Pure physics and numpy (no argparse, no ROS); ``damper-hil ride-study`` is a thin front end
and ``docs/ride_study.md`` reports the results.  Conventions as in
:mod:`ride_sim.quarter_car`: ``SWS = z1 − z2`` (+ = suspension compressed), body
acceleration up +, ``DTL`` the deviation from the static tyre load (+ = more load), all SI.

This module runs the figures (:func:`figure10`, :func:`figure11`, :func:`figure13`).  Beside
it: :mod:`ride_sim.study_paper` (the representations, output keys and the paper's values),
:mod:`ride_sim.study_setup` (the settings and the dampers), :mod:`ride_sim.study_runs` (the
roads at the simulation samples, one run, the metrics), :mod:`ride_sim.study_linear` (the
linear car's frequency-domain prediction) and :mod:`ride_sim.study_tables` (the text
tables).

Representations (:mod:`ride_sim.study_paper`)
---------------------------------------------
The paper's three (``REPRESENTATIONS``) and an extra column (``EXTRA_REPRESENTATIONS``),
built by :func:`ride_sim.study_setup.make_representation`:

- ``linear``: ``C_s = 2622 N s/m`` at the wheel (``C_s · MR² = 5899.5 N s/m`` at the
  damper), with the sport damper's gas preload as a constant force;
- ``14speed``: the 14-speed test simulated on the hysteretic model
  (:func:`~damper_emulator.model.representations.fourteen_speed_damper`, cached per
  process: :func:`~ride_sim.study_setup.fourteen_speed_table`);
- ``nonlinear``: the compressible (hysteretic) model stepped inside the 1 kHz loop;
- ``incompressible``: eqs 30–32 (an extra column).

Random road (figures 10 and 11)
-------------------------------
Eq 39 synthesised by :func:`ride_sim.road_synthesis.random_road` over the band
``road.band_cycles_per_m`` with the sample spacing ``V · dt`` (one road sample per
simulation step).  The synthesised road is exactly periodic with period ``length + V dt``;
the car drives ``road.lead_in_s`` of it (the end of the same road, so the road is
continuous) from static equilibrium at the starting height, and the statistics are taken
over exactly one period (the ``length_m`` of road).  With ``amplitudes="deterministic"``
every seed has exactly the target spectrum, so the linear car's r.m.s. values are
seed-independent and equal the frequency-domain prediction up to the damper's sampling;
seeds differ in phase only (which moves peaks and non-linear results).
``"random"`` gives the scatter of a single measured-like realisation (as the paper's
single road had); :func:`~ride_sim.study_linear.linear_prediction` also returns that
scatter analytically.

Pothole (figure 13)
-------------------
A sharp-edged rectangular pothole (:func:`ride_sim.road_features.pothole`) seen through a
rigid tyre of radius ``road.tyre_radius_m`` (:func:`ride_sim.road_envelope.envelope`),
averaged over ``road.contact_length_m``; r.m.s. values over ``[t_edge − window_before_s,
t_edge + window_after_s)`` with ``t_edge`` the time the wheel centre passes the leading
edge; peaks over the whole run.  The geometry and window were chosen so the linear column
of the paper's figure 13 is roughly matched (``docs/ride_study.md``).

Adaptive damper (``--figure adaptive``)
---------------------------------------
The hysteretic model with the solenoid bypass (:mod:`damper_emulator.model.adaptive`) on the
figure-10 random road: passive sport (command 1), passive comfort (command 0) and the
continuous skyhook law (:mod:`ride_sim.skyhook`, ``config/skyhook.yaml``) updated at
``rate_hz`` with a zero-order hold, the solenoid lag in the model.  All three run through
the same sampled loop (:func:`ride_sim.session.semi_active_run`; at a constant command it
equals :func:`~ride_sim.study_runs.run` exactly) on the same seeds; SWS, Wk-weighted body
acceleration and DTL r.m.s. per seed, their mean and spread, and per-seed ratios to
passive sport.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from damper_emulator.errors import UserError
from ride_sim.iso2631 import weight_signal
from ride_sim.params import QuarterCarParams, RoadParams
from ride_sim.quarter_car import simulate
from ride_sim.study_linear import linear_prediction
from ride_sim.study_paper import (
    ALL_REPRESENTATIONS,
    OUTPUT_KEYS,
    PAPER_CLAIM,
    PAPER_FIGURE_10,
    PAPER_FIGURE_11_CROSSING_M_S,
    PAPER_FIGURE_13,
    REPRESENTATIONS,
)
from ride_sim.study_runs import (
    check_random_road,
    metrics,
    pothole_input,
    random_road_input,
    run,
    run_linear_exact,
    seed_summary,
)
from ride_sim.study_setup import (
    StudySettings,
    band_at_speed,
    default_model,
    fourteen_speed_table,
    make_representation,
)

Progress = Callable[[str], None]


def quiet(_msg: str) -> None:
    pass


# --------------------------------------------------------------------------------------
# figure 10


@dataclass
class StudyResult:
    """A study's JSON document and the time histories kept for plots."""

    doc: dict[str, Any]
    traces: dict[str, Any] = dataclasses.field(default_factory=dict)


def figure10(settings: StudySettings, *, representations: Sequence[str] = ALL_REPRESENTATIONS,
             progress: Progress = quiet, keep_traces: bool = True) -> StudyResult:
    """Figure 10: ``road.length_m`` of random road at ``road.speed_m_s``, every
    representation on the same ``road.seeds`` seeds; means, spread, the paper's values and
    ratios, the linear frequency-domain prediction and the claim check."""
    started = time.perf_counter()
    road, car, dt = settings.road, settings.car, settings.dt_s
    speed = road.speed_m_s
    band = band_at_speed(road, speed)
    check_random_road(road, speed, dt)
    dampers = {}
    for kind in representations:
        if kind == "14speed":
            progress(f"building the {settings.points}-speed table on the hysteretic model ...")
        dampers[kind] = make_representation(kind, car, points=settings.points)
    per_seed: dict[str, list] = {k: [] for k in representations}
    faults: dict[str, int] = {k: 0 for k in representations}
    traces: dict[str, Any] = {}
    exact: list[dict[str, float]] = []
    for seed in range(road.seeds):
        heights, n_lead, n_eval = random_road_input(road, speed, seed, dt, band)
        progress(f"seed {seed + 1}/{road.seeds}: {road.length_m:g} m at {speed:g} m/s "
                 f"({n_lead + n_eval} steps) x {len(representations)} dampers")
        for kind in representations:
            res = run(car, dampers[kind], heights, dt)
            per_seed[kind].append(metrics(res, n_lead, n_lead + n_eval))
            faults[kind] |= res.fault_bits
            if keep_traces and seed == 0:
                traces[kind] = res
        if seed == 0 and "linear" in representations:
            ex = run_linear_exact(car, heights, dt)
            exact.append(metrics(ex, n_lead, n_lead + n_eval))
            if keep_traces:
                traces["linear_exact"] = ex
                traces["window"] = (n_lead, n_lead + n_eval)
    doc: dict[str, Any] = {
        "figure": 10,
        "title": f"{road.length_m:g} m of random road (G = {road.roughness:g}, "
                 f"p = {road.waviness:g}) at {speed:g} m/s",
        "units": {"sws": "m", "accel": "m/s^2", "dtl": "N"},
        "settings": settings.as_dict(),
        "band_cycles_per_m": list(band),
        "band_hz": [band[0] * speed, band[1] * speed],
        "representations": list(representations),
        "paper_accel_peak_note": "the paper's 'peak body accel' is compared with the "
                                 "unweighted peaks (accel_peak_*): they match it, the "
                                 "weighted ones (accel_w_peak_*) are 10-30 % lower",
        "sws_note": "sws_rms and sws_peak_* are about the static position; *_ac about the "
                    "mean SWS (sws_mean, the suspension packing of an asymmetric damper); "
                    "the paper's SWS values are compared with both",
    }
    for kind in representations:
        doc[kind] = seed_summary(per_seed[kind], PAPER_FIGURE_10.get(kind))
        doc[kind]["damper"] = dampers[kind].name
        doc[kind]["fault_bits"] = faults[kind]
    if "linear" in representations:
        pred = linear_prediction(car, road, speed, band)
        fd: dict[str, Any] = {"prediction": pred}
        keys = ("sws_rms", "accel_w_rms", "accel_rms", "dtl_rms")
        fd["time_domain_sampled_damper"] = {k: doc["linear"][k] for k in keys}
        fd["ratio_sampled_to_prediction"] = {k: doc["linear"][k] / pred[k] for k in keys}
        if exact:
            fd["time_domain_exact_linear_seed0"] = {k: exact[0][k] for k in keys}
            fd["ratio_exact_to_prediction"] = {k: exact[0][k] / pred[k] for k in keys}
        doc["frequency_domain"] = fd
    if "14speed" in representations and "nonlinear" in representations:
        doc["claim"] = claim_check(per_seed["nonlinear"], per_seed["14speed"])
    doc["elapsed_s"] = round(time.perf_counter() - started, 3)
    return StudyResult(doc, traces)


def claim_check(hysteretic: list[dict[str, float]], table: list[dict[str, float]]
                ) -> dict[str, Any]:
    """The paper's claim: for similar weighted acceleration and SWS, the hysteretic model
    predicts about 6 % lower r.m.s. DTL and about 10 % lower peak DTL than the 14-speed
    representation.

    Ratios hysteretic / 14-speed per seed (the same roads), their mean, std and standard
    error; peak DTL is the mean of |peak| over both signs.  A reduction *agrees* with the
    claimed one when they differ by at most ``max(2 standard errors, 2 %-points)``;
    ``reproduced`` when both agree and the weighted acceleration and SWS (about its mean)
    differ by less than 5 %.
    """
    def ratios(fn):
        r = np.array([fn(a) / fn(b) for a, b in zip(hysteretic, table)])
        std = float(r.std(ddof=1)) if r.size > 1 else 0.0
        return {"mean": float(r.mean()), "std": std, "sem": std / math.sqrt(r.size),
                "min": float(r.min()), "max": float(r.max())}

    def peak(m):
        return 0.5 * (abs(m["dtl_peak_pos"]) + abs(m["dtl_peak_neg"]))

    r = {"accel_w_rms": ratios(lambda m: m["accel_w_rms"]),
         "sws_rms": ratios(lambda m: m["sws_rms"]),
         "sws_rms_ac": ratios(lambda m: m["sws_rms_ac"]),
         "dtl_rms": ratios(lambda m: m["dtl_rms"]),
         "dtl_peak_pos": ratios(lambda m: m["dtl_peak_pos"]),
         "dtl_peak_neg": ratios(lambda m: m["dtl_peak_neg"]),
         "dtl_peak_abs": ratios(peak)}
    out: dict[str, Any] = {
        "statement": "for similar weighted acceleration and SWS the hysteretic model predicts "
                     "about 6 % lower r.m.s. DTL and about 10 % lower peak DTL than the "
                     "14-speed representation",
        "seeds": len(hysteretic),
        "ratio_nonlinear_to_14speed": r,
        "paper_table_ratio": {"dtl_rms": 1590.0 / 1690.0,
                              "dtl_peak_abs": (5330.0 + 5470.0) / (5860.0 + 5850.0)},
    }
    similar = (abs(r["accel_w_rms"]["mean"] - 1) < 0.05
               and abs(r["sws_rms_ac"]["mean"] - 1) < 0.05)
    out["similar_accel_and_sws"] = bool(similar)
    verdicts = {}
    for key, claim_key in (("dtl_rms", "dtl_rms_reduction"),
                           ("dtl_peak_abs", "dtl_peak_reduction")):
        reduction = 1.0 - r[key]["mean"]
        claimed = PAPER_CLAIM[claim_key]
        tol = max(2.0 * r[key]["sem"], 0.02)
        verdict = ("agrees" if abs(reduction - claimed) <= tol
                   else "smaller than claimed" if reduction < claimed
                   else "larger than claimed")
        out[claim_key] = reduction
        out[f"{claim_key}_sem"] = r[key]["sem"]
        out[f"{claim_key}_claimed"] = claimed
        verdicts[key] = verdict
    out["verdict"] = verdicts
    out["reproduced"] = bool(similar and all(v == "agrees" for v in verdicts.values()))
    return out


# --------------------------------------------------------------------------------------
# figure 13


def figure13(settings: StudySettings, *, representations: Sequence[str] = ALL_REPRESENTATIONS,
             progress: Progress = quiet) -> StudyResult:
    """Figure 13: the pothole at ``road.pothole_speed_m_s``.  r.m.s. over the window
    ``[t_edge − window_before_s, t_edge + window_after_s)``, peaks over the whole run."""
    started = time.perf_counter()
    road, car, dt = settings.road, settings.car, settings.dt_s
    speed = road.pothole_speed_m_s
    raw, env, heights, t_edge = pothole_input(road, speed, dt)
    i0 = max(0, int(round((t_edge - road.window_before_s) / dt)))
    i1 = min(heights.size, int(round((t_edge + road.window_after_s) / dt)))
    if i1 - i0 < 2:
        raise UserError("the pothole r.m.s. window holds fewer than 2 samples")
    doc: dict[str, Any] = {
        "figure": 13,
        "title": f"pothole {road.pothole_depth_m * 1e3:g} mm deep, "
                 f"{road.pothole_length_m:g} m long, at {speed:g} m/s",
        "units": {"sws": "m", "accel": "m/s^2", "dtl": "N"},
        "settings": settings.as_dict(),
        "pothole": {"depth_m": road.pothole_depth_m, "length_m": road.pothole_length_m,
                    "edges": "sharp (vertical walls)", "tyre_radius_m": road.tyre_radius_m,
                    "contact_length_m": road.contact_length_m, "speed_m_s": speed,
                    "tyre_path_min_m": float(env.height_m.min()),
                    "leading_edge_time_s": t_edge},
        "rms_window_s": [i0 * dt, i1 * dt],
        "peaks_window_s": [0.0, (heights.size - 1) * dt],
        "representations": list(representations),
        "paper_accel_note": "the paper's 'body accel' r.m.s. and peaks are compared with the "
                            "unweighted acceleration (accel_rms, accel_peak_*)",
    }
    traces: dict[str, Any] = {"raw": raw, "enveloped": env, "window": (i0, i1),
                              "speed_m_s": speed, "t_edge_s": t_edge}
    for kind in representations:
        progress(f"pothole at {speed:g} m/s: {kind} ({heights.size} steps)")
        damper = make_representation(kind, car, points=settings.points)
        res = simulate(car, damper, heights, dt)
        m = metrics(res, i0, i1)
        whole = metrics(res, 0, heights.size)
        for key in OUTPUT_KEYS:
            if "_peak_" in key:
                m[key] = whole[key]
        # no packing over a 0.2 s window: the SWS-about-its-mean keys are left out
        entry = {k: m[k] for k in OUTPUT_KEYS if not k.endswith("_ac") and k != "sws_mean"}
        paper = PAPER_FIGURE_13.get(kind)
        if paper:
            entry["paper"] = dict(paper)
            entry["ratio_to_paper"] = {k: m[k] / v for k, v in paper.items()}
        entry["damper"] = damper.name
        entry["fault_bits"] = res.fault_bits
        doc[kind] = entry
        traces[kind] = res
    doc["elapsed_s"] = round(time.perf_counter() - started, 3)
    return StudyResult(doc, traces)


# --------------------------------------------------------------------------------------
# figure 11: speed sweep in a process pool

_WORKER: dict[str, Any] = {}


def _init_worker(car: QuarterCarParams, road: RoadParams, dt_s: float, points: int,
                 table_v: np.ndarray | None, table_f: np.ndarray | None,
                 kinds: Sequence[str]) -> None:
    """Build the dampers once per worker and warm the JIT (compiled kernels are loaded
    from numba's on-disk cache) and the Wk filter design."""
    from damper_emulator.model.representations import TableDamper

    table = TableDamper(table_v, table_f) if table_v is not None else None
    _WORKER.clear()
    _WORKER.update(car=car, road=road, dt=dt_s)
    _WORKER["dampers"] = {k: make_representation(k, car, points=points, table=table)
                          for k in kinds}
    warm = np.zeros(200)
    warm[100:] = 1e-3
    for d in _WORKER["dampers"].values():
        res = simulate(car, d, warm, dt_s)
        weight_signal("Wk", res.body_accel_m_s2, 1.0 / dt_s)


def _sweep_task(speed: float, kind: str, seed: int) -> dict[str, Any]:
    t0 = time.perf_counter()
    car, road, dt = _WORKER["car"], _WORKER["road"], _WORKER["dt"]
    heights, n_lead, n_eval = random_road_input(road, speed, seed, dt)
    res = run(car, _WORKER["dampers"][kind], heights, dt)
    m = metrics(res, n_lead, n_lead + n_eval)
    return {"speed": speed, "kind": kind, "seed": seed, "metrics": m,
            "faults": res.fault_bits, "steps": heights.size,
            "elapsed_s": time.perf_counter() - t0}


def crossing_speed(speeds: Sequence[float], a: Sequence[float], b: Sequence[float]
                   ) -> list[float]:
    """Speeds where the curves ``a`` and ``b`` cross (linear interpolation)."""
    d = np.asarray(a, float) - np.asarray(b, float)
    v = np.asarray(speeds, float)
    out = []
    for i in range(d.size - 1):
        if d[i] == 0:
            out.append(float(v[i]))
        elif d[i] * d[i + 1] < 0:
            out.append(float(v[i] + (v[i + 1] - v[i]) * d[i] / (d[i] - d[i + 1])))
    if d.size and d[-1] == 0:
        out.append(float(v[-1]))
    return out


def figure11(settings: StudySettings, *, representations: Sequence[str] = REPRESENTATIONS,
             workers: int | None = None, progress: Progress = quiet) -> StudyResult:
    """Figure 11: r.m.s. outputs (weighted acceleration first) against speed on the random
    road, ``road.seeds`` seeds per speed and representation, in a process pool of
    ``workers`` processes (default: all cores; 1 runs in this process)."""
    started = time.perf_counter()
    road, car, dt = settings.road, settings.car, settings.dt_s
    speeds = [float(v) for v in road.sweep_speeds_m_s]
    for v in speeds:  # fail before any work (band vs Nyquist and road length)
        check_random_road(road, v, dt)
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise UserError(f"workers must be a positive integer, got {workers}")
    table_v = table_f = None
    if "14speed" in representations:
        progress(f"building the {settings.points}-speed table on the hysteretic model ...")
        table = fourteen_speed_table(default_model(), settings.points)
        table_v, table_f = np.asarray(table.velocity_m_s), np.asarray(table.force_n)
    # the slowest tasks first: low speed (long runs), hysteretic model
    cost = {"nonlinear": 4.0, "incompressible": 1.0, "14speed": 1.0, "linear": 1.0}
    tasks = [(v, k, s) for v in speeds for k in representations for s in range(road.seeds)]
    tasks.sort(key=lambda t: -cost.get(t[1], 1.0) / t[0])
    init = (car, road, dt, settings.points, table_v, table_f, tuple(representations))
    results: list[dict[str, Any]] = []
    n = len(tasks)
    report_every = max(1, n // 10)
    if workers == 1:
        _init_worker(*init)
        for i, task in enumerate(tasks, 1):
            results.append(_sweep_task(*task))
            if i % report_every == 0 or i == n:
                progress(f"speed sweep: {i}/{n} runs")
    else:
        progress(f"speed sweep: {n} runs ({len(speeds)} speeds x {len(representations)} "
                 f"dampers x {road.seeds} seeds) on {workers} worker processes ...")
        with concurrent.futures.ProcessPoolExecutor(max_workers=workers, initializer=_init_worker,
                                                    initargs=init) as pool:
            futures = [pool.submit(_sweep_task, *t) for t in tasks]
            for i, fut in enumerate(concurrent.futures.as_completed(futures), 1):
                results.append(fut.result())
                if i % report_every == 0 or i == n:
                    progress(f"speed sweep: {i}/{n} runs")
    doc: dict[str, Any] = {
        "figure": 11,
        "title": f"r.m.s. outputs against speed, {road.length_m:g} m of random road "
                 f"(G = {road.roughness:g}, p = {road.waviness:g})",
        "units": {"sws": "m", "accel": "m/s^2", "dtl": "N"},
        "settings": settings.as_dict(),
        "speeds_m_s": speeds,
        "band_cycles_per_m": {f"{v:g}": list(band_at_speed(road, v)) for v in speeds},
        "representations": list(representations),
        "workers": workers,
    }
    keys = ("accel_w_rms", "accel_rms", "sws_rms", "dtl_rms")
    for kind in representations:
        entry: dict[str, Any] = {}
        for key in keys:
            means, stds = [], []
            for v in speeds:
                x = np.array([r["metrics"][key] for r in results
                              if r["kind"] == kind and r["speed"] == v])
                means.append(float(x.mean()))
                stds.append(float(x.std(ddof=1)) if x.size > 1 else 0.0)
            entry[key] = means
            entry[f"{key}_std"] = stds
        entry["fault_bits"] = int(np.bitwise_or.reduce(
            [r["faults"] for r in results if r["kind"] == kind] or [0]))
        doc[kind] = entry
    if "linear" in representations:
        doc["linear_prediction_accel_w_rms"] = [
            linear_prediction(car, road, v)["accel_w_rms"] for v in speeds]
        for other in ("nonlinear", "14speed"):
            if other in representations:
                doc[f"crossing_linear_{other}_m_s"] = crossing_speed(
                    speeds, doc["linear"]["accel_w_rms"], doc[other]["accel_w_rms"])
    doc["paper_crossing_m_s"] = PAPER_FIGURE_11_CROSSING_M_S
    doc["runs"] = n
    doc["steps"] = int(sum(r["steps"] for r in results))
    doc["cpu_s"] = round(sum(r["elapsed_s"] for r in results), 3)
    doc["elapsed_s"] = round(time.perf_counter() - started, 3)
    return StudyResult(doc, {})
