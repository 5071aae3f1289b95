"""Frequency-domain r.m.s. of the linear car on the band-limited eq-39 road (Simms & Crolla,
SAE 2002-01-0319): the prediction a ride study's linear column is checked against, its
seed-to-seed scatter, and the band of the synthesised road that best matches a target."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ride_sim.frequency_domain import transfer_functions
from ride_sim.iso2631 import frequency_weighting
from ride_sim.params import QuarterCarParams, RoadParams
from ride_sim.study_setup import band_at_speed


def linear_prediction(car: QuarterCarParams, road: RoadParams, speed_m_s: float,
                      band_cycles_per_m: Sequence[float] | None = None, *,
                      damping_ns_m: float | None = None,
                      points: int = 20000) -> dict[str, float]:
    """Frequency-domain r.m.s. of the linear car on the band-limited eq-39 road.

    ``√∫ |H(f)|² S(f) df`` over ``f ∈ V [n_min, n_max]`` with ``S(f) = G V^(p−1) f^(−p)``
    and ``H`` from :func:`~ride_sim.frequency_domain.transfer_functions` (weighted
    acceleration: ``H · Wk``).  Returns ``sws_rms``, ``accel_w_rms``, ``accel_rms``,
    ``dtl_rms`` and, for a random-amplitude road of this length, the coefficient of
    variation of each r.m.s. between realisations (``*_cv``): each FFT bin's power is
    exponentially distributed, so the mean square has relative std
    ``√Σ q_k² / Σ q_k`` (``q_k`` = bin powers of the output) and the r.m.s. about half that.
    """
    lo, hi = band_at_speed(road, speed_m_s) if band_cycles_per_m is None else \
        band_cycles_per_m
    v = float(speed_m_s)
    f = np.geomspace(lo * v, hi * v, points)
    s = road.roughness * v ** (road.waviness - 1.0) * f ** (-road.waviness)
    h = transfer_functions(car, f, damping_ns_m)
    w = frequency_weighting("Wk", f)
    gains = {"sws_rms": h.sws, "accel_w_rms": h.body_accel * w, "accel_rms": h.body_accel,
             "dtl_rms": h.dtl}
    out = {k: float(np.sqrt(np.trapezoid(np.abs(g) ** 2 * s, f))) for k, g in gains.items()}
    # bin powers of a road of this length (bins 1/P cycles/m wide, P = length)
    dn = 1.0 / road.length_m
    centres = np.arange(math.ceil(lo / dn - 0.5), math.floor(hi / dn + 0.5) + 1) * dn
    centres = centres[centres > 0]
    if centres.size:
        edges_lo = np.clip(centres - dn / 2, lo, hi)
        edges_hi = np.clip(centres + dn / 2, lo, hi)
        p = road.waviness
        power = road.roughness * (edges_lo ** (1 - p) - edges_hi ** (1 - p)) / (p - 1) \
            if p != 1 else road.roughness * np.log(edges_hi / edges_lo)
        hb = transfer_functions(car, centres * v, damping_ns_m)
        wb = frequency_weighting("Wk", centres * v)
        gb = {"sws_rms": hb.sws, "accel_w_rms": hb.body_accel * wb,
              "accel_rms": hb.body_accel, "dtl_rms": hb.dtl}
        for k, g in gb.items():
            q = np.abs(g) ** 2 * power
            out[k.replace("_rms", "_cv")] = float(0.5 * np.sqrt(np.sum(q ** 2)) / np.sum(q))
    return out


def band_sensitivity(car: QuarterCarParams, road: RoadParams, speed_m_s: float,
                     n_min: Sequence[float], n_max: Sequence[float],
                     points: int = 40000) -> dict[str, np.ndarray]:
    """Linear frequency-domain r.m.s. on a grid of band edges (``len(n_min) × len(n_max)``
    arrays per output; NaN where ``n_min >= n_max``), from cumulative integrals on one
    log grid spanning all edges."""
    n_min = np.asarray(n_min, dtype=float)
    n_max = np.asarray(n_max, dtype=float)
    v = float(speed_m_s)
    f = np.geomspace(min(n_min.min(), n_max.min()) * v, max(n_min.max(), n_max.max()) * v,
                     points)
    s = road.roughness * v ** (road.waviness - 1.0) * f ** (-road.waviness)
    h = transfer_functions(car, f)
    w = frequency_weighting("Wk", f)
    out: dict[str, np.ndarray] = {"n_min": n_min, "n_max": n_max}
    for key, g in (("sws_rms", h.sws), ("accel_w_rms", h.body_accel * w),
                   ("accel_rms", h.body_accel), ("dtl_rms", h.dtl)):
        y = np.abs(g) ** 2 * s
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(f))])
        c_lo = np.interp(n_min * v, f, cum)
        c_hi = np.interp(n_max * v, f, cum)
        grid = c_hi[None, :] - c_lo[:, None]
        grid = np.where(n_min[:, None] < n_max[None, :], grid, np.nan)
        out[key] = np.sqrt(np.maximum(grid, 0.0))
    return out


def best_band(car: QuarterCarParams, road: RoadParams, speed_m_s: float,
              target: Mapping[str, float], n_min: Sequence[float],
              n_max: Sequence[float]) -> dict[str, Any]:
    """The band of the grid whose linear ``sws_rms``, ``accel_w_rms``, ``dtl_rms`` come
    closest to ``target`` (smallest largest relative error)."""
    grid = band_sensitivity(car, road, speed_m_s, n_min, n_max)
    keys = ("sws_rms", "accel_w_rms", "dtl_rms")
    err = np.max(np.stack([np.abs(grid[k] / target[k] - 1.0) for k in keys]), axis=0)
    err = np.where(np.isnan(err), np.inf, err)
    i, j = np.unravel_index(int(np.argmin(err)), err.shape)
    return {"band_cycles_per_m": [float(grid["n_min"][i]), float(grid["n_max"][j])],
            "max_relative_error": float(err[i, j]),
            **{k: float(grid[k][i, j]) for k in keys}}
