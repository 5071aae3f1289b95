"""One run of a ride study: the road heights at the simulation samples (the random road
and the enveloped pothole), the quarter car driven from static equilibrium at the starting
height, and the metrics of a run (:data:`~ride_sim.study_paper.OUTPUT_KEYS`) and their
summary over seeds."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ride_sim.iso2631 import weight_signal
from ride_sim.params import QuarterCarParams, RoadParams
from ride_sim.quarter_car import QuarterCar, RideResult, simulate
from ride_sim.road import RoadProfile
from ride_sim.road_envelope import envelope
from ride_sim.road_features import DEFAULT_FEATURE_SPACING_M, pothole
from ride_sim.road_speed import road_input
from ride_sim.road_synthesis import random_road
from ride_sim.study_paper import OUTPUT_KEYS
from ride_sim.study_setup import band_at_speed

# --------------------------------------------------------------------------------------
# roads at the simulation samples


def random_road_input(road: RoadParams, speed_m_s: float, seed: int, dt_s: float,
                      band_cycles_per_m: Sequence[float] | None = None
                      ) -> tuple[np.ndarray, int, int]:
    """Road height at the simulation samples: ``(heights, n_lead, n_eval)``.

    The road (:func:`~ride_sim.road_synthesis.random_road`, spacing ``V dt``) is one period
    of ``n_eval`` samples; ``n_lead`` samples of its end are driven first (periodic wrap, so
    the road is continuous) and discarded.
    """
    band = band_at_speed(road, speed_m_s) if band_cycles_per_m is None else band_cycles_per_m
    profile = random_road(road.roughness, road.waviness, road.length_m,
                          band_cycles_per_m=band, spacing_m=speed_m_s * dt_s, seed=seed,
                          amplitudes=road.amplitudes)
    h = profile.height_m
    n_eval = h.size
    n_lead = int(round(road.lead_in_s / dt_s))
    return h[np.arange(-n_lead, n_eval) % n_eval], n_lead, n_eval


def check_random_road(road: RoadParams, speed_m_s: float, dt_s: float) -> None:
    """Raise :class:`~ride_sim.road.RoadError` (one line) now if the random road at
    ``speed_m_s`` cannot be synthesised (band beyond Nyquist, road shorter than the band's
    longest wavelength), before any damper is built."""
    random_road(road.roughness, road.waviness, road.length_m,
                band_cycles_per_m=band_at_speed(road, speed_m_s),
                spacing_m=speed_m_s * dt_s, seed=0, amplitudes=road.amplitudes)


def pothole_input(road: RoadParams, speed_m_s: float, dt_s: float
                  ) -> tuple[RoadProfile, RoadProfile, np.ndarray, float]:
    """``(raw profile, enveloped profile, heights at the samples, t_edge)`` of the
    study's pothole driven at ``speed_m_s``; ``t_edge`` [s] is when the wheel centre is
    over the leading edge."""
    length = road.pothole_length_m
    spacing = length / max(2, math.ceil(length / DEFAULT_FEATURE_SPACING_M - 1e-9))
    raw = pothole(road.pothole_depth_m, length, lead_in_m=road.pothole_lead_in_m,
                  lead_out_m=road.pothole_lead_out_m, spacing_m=spacing)
    contact = road.contact_length_m if road.contact_length_m > 0 else None
    env = envelope(raw, road.tyre_radius_m, contact)
    inside = np.flatnonzero(raw.height_m < 0)
    edge_m = float(raw.distance_m[inside[0] - 1])
    n = int(math.floor(raw.end_m / (speed_m_s * dt_s) + 1e-9)) + 1
    t = np.arange(n) * dt_s
    heights, _ = road_input(env, speed_m_s, t)
    return raw, env, heights, edge_m / speed_m_s


# --------------------------------------------------------------------------------------
# one run


def start_state(heights: np.ndarray, dt_s: float) -> tuple[float, float, float, float]:
    """Static equilibrium at the starting road height, moving with the road."""
    h0 = float(heights[0])
    v0 = float(heights[1] - heights[0]) / dt_s if heights.size > 1 else 0.0
    return (h0, v0, h0, v0)


def run(car: QuarterCarParams, damper, heights: np.ndarray, dt_s: float) -> RideResult:
    """:func:`~ride_sim.quarter_car.simulate` from equilibrium at the starting height."""
    return simulate(car, damper, heights, dt_s, initial_state=start_state(heights, dt_s))


def run_linear_exact(car: QuarterCarParams, heights: np.ndarray, dt_s: float) -> RideResult:
    """The linear car with ``C_s`` inside the exact update (no sampled damper): the
    reference that isolates the damper's zero-order-hold sampling."""
    qc = QuarterCar(car, dt_s, 0.0, car.linear_damping_ns_m)
    qc.reset(start_state(heights, dt_s))
    n = heights.size
    out = np.empty((3, n))
    h = heights.tolist()
    for k in range(n):
        u1 = h[k + 1] if k + 1 < n else 2.0 * h[k] - h[k - 1]
        out[:, k] = qc.outputs(0.0, h[k], u1)
        qc.advance(0.0, h[k], u1)
    t = np.arange(n) * dt_s
    z = np.zeros(n)
    return RideResult(t, np.asarray(heights, float), out[0], out[1], out[2], z, z, z, z, z, z,
                      z, np.zeros(n, dtype=np.int64), "linear (exact)", dt_s)


# --------------------------------------------------------------------------------------
# metrics


def metrics(result: RideResult, start: int, stop: int) -> dict[str, float]:
    """:data:`OUTPUT_KEYS` over samples ``[start, stop)``; the Wk filter runs over the
    whole record (its start transient settles in the lead-in)."""
    return history_metrics(result.sws_m, result.body_accel_m_s2, result.dtl_n, result.dt_s,
                           start, stop)


def history_metrics(sws_m: np.ndarray, body_accel_m_s2: np.ndarray, dtl_n: np.ndarray,
                    dt_s: float, start: int, stop: int) -> dict[str, float]:
    """:func:`metrics` of the histories of one run (e.g. one row of
    :func:`ride_sim.many.simulate_many`'s result)."""
    aw = weight_signal("Wk", body_accel_m_s2, 1.0 / dt_s)
    sl = slice(start, stop)
    out: dict[str, float] = {}
    for key, x in (("sws", sws_m[sl]), ("accel_w", aw[sl]),
                   ("accel", body_accel_m_s2[sl]), ("dtl", dtl_n[sl])):
        out[f"{key}_rms"] = float(np.sqrt(np.mean(x * x)))
        out[f"{key}_peak_pos"] = float(np.max(x))
        out[f"{key}_peak_neg"] = float(np.min(x))
    sws = sws_m[sl]
    mean = float(np.mean(sws))
    out["sws_mean"] = mean
    out["sws_rms_ac"] = float(np.sqrt(np.mean((sws - mean) ** 2)))
    out["sws_peak_pos_ac"] = float(np.max(sws)) - mean
    out["sws_peak_neg_ac"] = float(np.min(sws)) - mean
    return {k: out[k] for k in OUTPUT_KEYS}


def seed_summary(per_seed: list[dict[str, float]], paper: Mapping[str, float] | None
             ) -> dict[str, Any]:
    """Means of each key, their spread over seeds, the paper's values and ratios."""
    doc: dict[str, Any] = {}
    spread: dict[str, Any] = {}
    for key in OUTPUT_KEYS:
        x = np.array([m[key] for m in per_seed])
        doc[key] = float(x.mean())
        spread[key] = {"std": float(x.std(ddof=1)) if x.size > 1 else 0.0,
                       "min": float(x.min()), "max": float(x.max())}
    doc["spread"] = spread
    doc["seeds"] = len(per_seed)
    doc["per_seed"] = per_seed
    if paper:
        doc["paper"] = dict(paper)
        doc["ratio_to_paper"] = {k: doc[k] / v for k, v in paper.items()}
    return doc
