"""How well a damper-in-the-loop run followed its simulation, and what it found.

:func:`tracking` gives the real-time hybrid simulation community's tracking criteria of
the measured stroke against the car's (the target): the normalised r.m.s. error, the peak
error and the residual delay (the lag that best aligns them, below a sample by a parabola
through the cross-correlation's peak).  :func:`summary` assembles ``hybrid.json``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ride_sim.hybrid.compensator import force_path_gain
from ride_sim.hybrid.host import RIDE_KEYS, HybridHost
from ride_sim.hybrid.rig_host import RigHost
from ride_sim.hybrid.transfer import stall_count, usable_cycles

#: The twin's residual is also reported over the ride's first and last this long [s].
TWIN_WINDOW_S = 2.0
#: Lags searched for the residual delay, ± [samples].
MAX_LAG_SAMPLES = 50


def residual_delay_s(target: np.ndarray, measured: np.ndarray, dt_s: float) -> float:
    """The delay [s] of ``measured`` behind ``target`` (negative: ahead) that maximises
    their cross-correlation, refined below a sample by the parabola through the peak and
    its neighbours."""
    a = np.asarray(target, float) - np.mean(target)
    b = np.asarray(measured, float) - np.mean(measured)
    n = a.size
    m = min(MAX_LAG_SAMPLES, n // 4)
    lags = np.arange(-m, m + 1)
    c = np.array([np.dot(b[max(0, lag): n + min(0, lag)], a[max(0, -lag): n - max(0, lag)])
                  for lag in lags])
    i = int(np.argmax(c))
    shift = 0.0
    if 0 < i < c.size - 1:
        den = c[i - 1] - 2.0 * c[i] + c[i + 1]
        if den < 0:
            shift = 0.5 * (c[i - 1] - c[i + 1]) / den
    return float((lags[i] + shift) * dt_s)


def _errors(target: np.ndarray, measured: np.ndarray) -> tuple[float, float]:
    """``(nrms, peak)``: the r.m.s. of measured − target over the target's r.m.s., and the
    largest error [m] (NaN where there is nothing to compare)."""
    target = np.asarray(target, float)
    error = np.asarray(measured, float) - target
    scale = float(np.sqrt(np.mean(target ** 2))) if target.size else 0.0
    return (float(np.sqrt(np.mean(error ** 2))) / scale if scale > 0 else math.nan,
            float(np.max(np.abs(error))) if error.size else math.nan)


def tracking(target: np.ndarray, measured: np.ndarray, dt_s: float) -> dict[str, float]:
    """``nrms`` (r.m.s. of measured − target over the target's r.m.s.), ``peak_error_m``,
    ``delay_ms`` (:func:`residual_delay_s`)."""
    nrms, peak = _errors(target, measured)
    return {"nrms": nrms, "peak_error_m": peak,
            "delay_ms": residual_delay_s(target, measured, dt_s) * 1e3}


def _stall_windows(host: RigHost, ridden: slice) -> np.ndarray:
    """The ridden samples a stall disturbed, each with ``stall_guard_s`` after it."""
    return ~usable_cycles(host.stalled[ridden], host.stall_guard_cycles)


def outside_stalls(host: RigHost, ridden: slice) -> dict[str, float | int]:
    """The tracking's ``nrms`` and ``peak_error_m`` over the ridden samples outside the
    stalls' windows (:func:`_stall_windows`), and how many samples those windows hold."""
    inside = _stall_windows(host, ridden)
    nrms, peak = _errors(host.record[0, ridden][~inside], host.record[2, ridden][~inside])
    return {"nrms_outside_stalls": nrms, "peak_error_outside_stalls_m": peak,
            "samples_in_stalls": int(np.count_nonzero(inside))}


def stall_summary(host: RigHost, ridden: slice) -> dict[str, float | int]:
    """The stalls the host saw: over the ride, ``count`` (runs of disturbed samples) and
    ``samples`` (disturbed); ``held_cycles``, the backlog's cycles the run held (the rig
    stood: :meth:`~ride_sim.hybrid.rig_host.RigHost._hold`); ``longest_ms`` in any phase
    (the longest a cycle ran behind the rig's beat)."""
    s = host.stalled[ridden]
    return {"count": stall_count(s),
            "samples": int(np.count_nonzero(s)),
            "held_cycles": host.held_cycles,
            "longest_ms": host.longest_stall_s * 1e3}


def summary(host: HybridHost) -> dict[str, Any]:
    """The run's ``hybrid.json`` (without the link's and the files' parts): status,
    reason, tracking, ride and reference metrics, twin, transfer system, stability."""
    completed = host.phase == "done"
    doc: dict[str, Any] = {"status": "completed" if completed else "stopped",
                           "reason": host.reason or "", "phase_at_end": host.phase}
    k = host.k
    sl = host.road.evaluated
    rec = host.record
    ridden = slice(sl.start, min(sl.stop, k))
    if ridden.stop - ridden.start > 10:
        doc["tracking"] = tracking(rec[0, ridden], rec[2, ridden], host.dt_s)
        doc["tracking"]["samples"] = ridden.stop - ridden.start
        # cycles whose feedback never came: they hold the last measurement
        doc["tracking"]["samples_without_measurement"] = int(
            np.count_nonzero(~host.fresh[ridden]))
        doc["tracking"].update(outside_stalls(host, ridden))
    else:
        doc["tracking"] = None
    doc["stalls"] = stall_summary(host, ridden)
    if host.tracker is not None:
        doc["tracking_delay_estimate_ms"] = host.tracker.delay_s * 1e3
        doc["tracking_gain_estimate"] = host.tracker.gain
        doc["tracking_updates"] = host.tracker.updates
    ride = host.ride_metrics()
    doc["ride"] = {key: ride[key] for key in RIDE_KEYS} if ride is not None else None
    doc["reference"] = {key: host.reference_metrics[key] for key in RIDE_KEYS}
    doc["ride_vs_reference"] = ({key: ride[key] / host.reference_metrics[key] - 1.0
                                 for key in RIDE_KEYS} if ride is not None else None)
    residual = rec[3, :k] - rec[4, :k]
    window = max(1, int(round(TWIN_WINDOW_S / host.dt_s)))
    doc["twin"] = _residuals(residual, ridden, window)
    online = host.online
    doc["twin"]["online"] = {
        "enabled": online.enabled, "updates": online.updates, "terms": online.terms(),
        # the twin as it came to the ride, the online correction left out
        "without": _residuals(rec[3, :k] - host.twin_raw[:k], ridden, window)}
    doc["static_force_n"] = host.static_force_n
    doc["identification"] = host.identification_report()
    if host.transfer is not None:
        slope = host.twin_slope_ns_m
        gain, at_hz = force_path_gain(host.compensator_params, host.transfer, host.car, slope,
                                      host.dt_s)
        doc["transfer"] = host.transfer.to_dict()
        doc["stability"] = {"force_path_gain": gain, "at_hz": at_hz,
                            "damper_slope_ns_m": slope,
                            "small_gain_margin": (1.0 / gain if gain > 0 else math.inf)}
        # the loop's gain is proportional to the damper's slope: the margin for the twin
        # as the online correction left it
        online_slope = online.slope()
        online_gain = gain * online_slope / slope if slope > 0 else gain
        doc["stability"]["online"] = {
            "damper_slope_ns_m": online_slope,
            "small_gain_margin": 1.0 / online_gain if online_gain > 0 else math.inf}
    safety = host.safety
    doc["safety"] = {"clamped_demands": safety.clamped,
                     "error_ratio_max": max(safety.error_ratios, default=math.nan),
                     # on the host's monotonic clock [s]: when the run stopped, and the
                     # last valid feedback before it
                     "stopped_at_s": safety.stopped_at_s,
                     "last_valid_feedback_s": safety.last_valid_s}
    return doc


def _residuals(residual: np.ndarray, ridden: slice, window: int) -> dict[str, float]:
    """The r.m.s. of a twin's ``residual`` over every sample, and over the ride's first
    and last ``window`` samples [N]."""
    return {"residual_rms_n": _rms(residual),
            "residual_rms_first_n": _rms(residual[ridden][:window]),
            "residual_rms_last_n": _rms(residual[ridden][-window:])}


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if x.size else math.nan
