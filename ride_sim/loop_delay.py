"""The loop delay of a hardware-in-the-loop ride, and the bound it must stay within.

In a real-time ride (``ride.clock: realtime``) the force applied at sample ``k`` was
computed from the state of an earlier sample ``k − d``; ``d`` samples of ``dt`` are the
loop's delay *in the simulation's own time*: transport and compute, plus every period the
emulator's loop stalled while the ride went on (a ride loop that stalls itself skips its
deadlines and loses no simulated time).  A damper force ``c ẋ(t − τ)`` acting on an
oscillation of angular frequency ω damps it by ``c cos(ωτ)``: it damps nothing at
``ωτ = π/2`` and pumps energy in beyond.  The fastest mode the damper must damp is the
wheel hop, ``ω_wh = √((K_s + K_t) / M_w)`` (eq 38's wheel on the suspension spring and the
tyre); the bound is the delay at which the wheel hop's damping has lost
:data:`MAX_PHASE_LAG` of phase.

This module holds the bound and the summary of a run's delays; the ride node
(:mod:`ride_sim.node`) measures them.  No ROS import.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ride_sim.params import QuarterCarParams

#: Phase the delayed damper force may lag at the wheel hop: 45°, where the damping it gives
#: is cos 45° = 71 % of the undelayed damper's (at 90° it gives none).
MAX_PHASE_LAG = math.pi / 4.0


def wheel_hop_rad_s(car: QuarterCarParams) -> float:
    """Wheel-hop angular frequency ``√((K_s + K_t) / M_w)`` [rad/s] (the body held still)."""
    return math.sqrt((car.spring_rate_n_m + car.tyre_stiffness_n_m) / car.unsprung_mass_kg)


def delay_bound_s(car: QuarterCarParams) -> float:
    """The loop delay [s] at which the damper force lags :data:`MAX_PHASE_LAG` at the wheel
    hop: ``MAX_PHASE_LAG / ω_wh``."""
    return MAX_PHASE_LAG / wheel_hop_rad_s(car)


def summarise(delays: NDArray[np.int64], dt_s: float, bound_s: float) -> dict[str, Any]:
    """The JSON block of a run's loop delays (``delays``: samples, one per sample the
    ride advanced; negative where the force answered no known state, e.g. the static
    force before the emulator's first).  Percentiles and maximum in ms; ``over_bound``:
    samples whose delay exceeded ``bound_s``; ``within_bound``: none did."""
    d = np.asarray(delays)
    known = d[d >= 0] * dt_s * 1e3
    over = int(np.count_nonzero(known > bound_s * 1e3))
    if known.size == 0:
        p50 = p99 = peak = math.nan
    else:
        p50, p99 = (float(v) for v in np.percentile(known, (50, 99)))
        peak = float(known.max())
    return {"samples": int(known.size), "p50_ms": p50, "p99_ms": p99, "max_ms": peak,
            "bound_ms": bound_s * 1e3, "over_bound": over,
            "within_bound": known.size > 0 and over == 0}


def warning(delay: Mapping[str, Any]) -> str | None:
    """One line for a run whose :func:`summarise` block is over its bound (``None``
    within it): the ride node logs it, the demo prints it."""
    if delay["within_bound"]:
        return None
    return (f"the loop delay exceeded its bound ({delay['bound_ms']:.1f} ms, the damper "
            f"force {math.degrees(MAX_PHASE_LAG):.0f}° late at the wheel hop) at "
            f"{delay['over_bound']} of {delay['samples']} samples (max "
            f"{delay['max_ms']:.0f} ms): a slow host or a stalled emulator; the ride's "
            "metrics are not the damper's alone")
