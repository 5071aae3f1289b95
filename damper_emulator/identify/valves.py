"""Chirp fit of the valve parameters (Simms & Crolla §3, eqs 8–33).

The incompressible model (eqs 30–32) is fitted per direction to chirp data after the
paper's hysteresis filter: only samples where velocity and acceleration differ in sign
(the decelerating part of each half cycle) are kept.  The gas force is that of the
quasi-static fit at the measured stroke (eq 37; the paper holds it at the static value,
which differs by ±16 N over the ±16 mm of the default chirp), and friction is the
quasi-static friction.  The residual Jacobian is exact: the analytic derivatives of the
compiled valve characteristic (:func:`damper_emulator.model.valve.pressure_drop_jacobian`).

Start values come from the data: the measured pressure drop ``Δp = (F − F_gas − F_f sgn ẋ)
/ (A_pt − A_rod)`` against flow ``Q = |ẋ| (A_pt − A_rod)``, binned, gives

* ``K_leak + K_port`` from the low-flow bins (closed valve, eq 15: ``Δp = K ν^¼ Q^(7/4)``);
* ``Δp0``, ``K_spring`` and ``K_port`` from a fit of ``Δp ≈ a + b Q + c Q^(7/4)`` to the
  high-flow bins (open valve: the preload, the blow-off spring rate ``∂Δp/∂Q ≈
  K_spring / √Δp`` from eq 10, and the port term of eq 27);
* ``G = 1.5``, the middle of the usual range.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping

import numpy as np
from numpy.typing import ArrayLike

from damper_emulator.identify.fitting import FitResult, Jacobian, fit
from damper_emulator.identify.quasi_static import IdentificationError
from damper_emulator.model.valve import (
    FLOW_EXPONENT,
    blow_off_coefficients,
    pressure_drop_array,
    pressure_drop_jacobian,
    pressure_drop_slope,
)

NAMES = ("k_leak", "k_port", "k_spring", "preload_pa", "smoothing_g")
#: Samples slower than this fraction of the direction's peak speed are left out: near a
#: reversal friction switches and the pressure lag of the real (compressible) damper
#: dominates.
MIN_SPEED_FRACTION = 0.02
#: Quantile bins of the start-value curve.
START_BINS = 40
#: Fraction of the bins (lowest flows) taken as the closed-valve regime for the start.
CLOSED_FRACTION = 0.15
#: Fraction of the bins (highest flows) taken as the open-valve regime for the start.
OPEN_FRACTION = 0.5
#: The preload starts at no less than this fraction of the largest binned pressure drop.
START_MIN_PRELOAD_FRACTION = 0.05
#: Start value of the smoothing exponent G (eq 28).
G_START = 1.5
#: Log-scaled bounds: each constant within this factor of its start; G in [G_MIN, G_MAX].
K_BOUND_FACTOR = 1e3
G_MIN, G_MAX = 0.5, 6.0
#: The eq 29 extension of the open branch below the blow-off point, ``H0 + H1 (Q − B0)``,
#: is negative at ``Q = 0`` when ``ρ = H1 B0 / H0 > 1`` (small preloads, soft springs);
#: eq 28 then gives a negative pressure drop at low flow and the characteristic cannot be
#: inverted.  The valve fit keeps ``ρ <= 1 − INTERCEPT_MARGIN`` with a penalty row of this
#: weight (times the r.m.s. measured valve force).
INTERCEPT_MARGIN = 1e-3
MONOTONIC_PENALTY = 1e3
#: Relative complex step of the penalty's gradient.
COMPLEX_STEP = 1e-20


def hysteresis_filter(velocity: ArrayLike, acceleration: ArrayLike) -> np.ndarray:
    """The paper's filter: keep samples where velocity and acceleration differ in sign."""
    keep: np.ndarray = np.asarray(velocity) * np.asarray(acceleration) < 0
    return keep


def start_values(q: np.ndarray, dp: np.ndarray, nu_m2_s: float) -> np.ndarray:
    """Valve start values ``(k_leak, k_port, k_spring, preload_pa, G)`` from measured
    ``Δp(Q)`` of one direction (see the module docstring)."""
    order = np.argsort(q)
    q, dp = q[order], dp[order]
    edges = np.linspace(0, q.size, START_BINS + 1).astype(int)
    qb = np.array([np.median(q[a:b]) for a, b in itertools.pairwise(edges) if b > a])
    pb = np.array([np.median(dp[a:b]) for a, b in itertools.pairwise(edges) if b > a])
    ok = (qb > 0) & (pb > 0)
    qb, pb = qb[ok], pb[ok]
    if qb.size < 6:
        raise IdentificationError("too few usable chirp samples in one direction to start "
                                  "the valve fit (need flow and a positive pressure drop)")
    nu4 = nu_m2_s ** 0.25
    n_closed = max(2, int(CLOSED_FRACTION * qb.size))
    k_total = float(np.median(pb[:n_closed] / (nu4 * qb[:n_closed] ** FLOW_EXPONENT)))
    hi = slice(int((1 - OPEN_FRACTION) * qb.size), None)
    basis = np.column_stack((np.ones(qb[hi].size), qb[hi], qb[hi] ** FLOW_EXPONENT))
    a, b, c = np.linalg.lstsq(basis, pb[hi], rcond=None)[0]
    preload = a if 0 < a < pb[-1] else 0.5 * float(np.median(pb[hi]))
    # an intercept near zero (a characteristic linear from Q = 0) would confine the
    # preload, bounded to a factor K_BOUND_FACTOR of its start, to a negligible value
    preload = max(preload, START_MIN_PRELOAD_FRACTION * float(pb[-1]))
    k_port = c / nu4 if c > 0 else 1e-3 * k_total
    k_port = min(k_port, 0.5 * k_total)
    slope = b if b > 0 else float(np.ptp(pb[hi]) / max(np.ptp(qb[hi]), 1e-30))
    k_spring = max(slope, 1e-30) * np.sqrt(float(np.median(pb[hi])))
    return np.array([k_total - k_port, k_port, k_spring, preload, G_START])


def extension_intercept_excess(theta: ArrayLike, nu_m2_s: float) -> tuple[float, np.ndarray]:
    """``ρ − (1 − INTERCEPT_MARGIN)`` with ``ρ = H1 B0 / H0 = (7/4)(K_leak/B1 + K_port) /
    (K_leak + K_port)`` (eqs 29, 47 and the corrected eq 48), and its gradient with respect
    to the five valve parameters (complex step)."""
    def rho(th: np.ndarray) -> complex:
        k_leak, k_port, k_spring, preload = th[0], th[1], th[2], th[3]
        _b0, b1, _b2, _b3 = blow_off_coefficients(k_leak, k_spring, preload, nu_m2_s)
        value: complex = FLOW_EXPONENT * (k_leak / b1 + k_port) / (k_leak + k_port)
        return value

    theta = np.asarray(theta, dtype=float)
    value = float(np.real(rho(theta)))
    grad = np.zeros(theta.size)
    for k in range(4):
        h = COMPLEX_STEP * abs(theta[k])
        th = theta.astype(complex)
        th[k] += 1j * h
        grad[k] = rho(th).imag / h
    return value - (1.0 - INTERCEPT_MARGIN), grad


def effective_variance_weights(q: np.ndarray, flow_sd_m3_s: float | np.ndarray,
                               force_sd_n: float, area_m2: float, valve: Iterable[float],
                               nu_m2_s: float, form: str = "cardano") -> np.ndarray:
    """Weights that account for noise in the flow as well as in the force.

    The compressibility-corrected flow carries the noise of the pressure derivative
    (standard deviation ``flow_sd_m3_s``); where ``Δp(Q)`` is steep (low flow) that noise
    becomes a large pressure error.  Weighting each residual by ``σ_F / √(σ_F² + (A dΔp/dQ
    σ_Q)²)`` (the effective-variance method for errors in both variables) keeps these
    samples from biasing the fit.
    """
    slope = area_m2 * pressure_drop_slope(q, valve, nu_m2_s, form) * flow_sd_m3_s
    return force_sd_n / np.sqrt(force_sd_n ** 2 + slope ** 2)


def fit_valve(q: np.ndarray, dp_measured: np.ndarray, area_m2: float, nu_m2_s: float,
              form: str = "cardano", start: ArrayLike | None = None,
              weights: ArrayLike | None = None, fixed: Mapping[str, float] | None = None,
              anchor: ArrayLike | None = None) -> FitResult:
    """Fit one valve direction's ``Δp(Q)`` to measured pressure drops.

    The residual is in force units: ``(A_pt − A_rod)(Δp_model − Δp_measured)`` [N].

    Parameters
    ----------
    q, dp_measured : ndarray
        Flow magnitudes [m³/s] and pressure drop magnitudes [Pa] of one direction.
    area_m2 : float
        ``A_pt − A_rod``.
    start : array_like, optional
        Start values; by default :func:`start_values` of the data.
    weights : array_like, optional
        Per-sample weights of the residual (see :func:`effective_variance_weights`).
    fixed : mapping of str to float, optional
        Parameters (names of :data:`NAMES`) held at the given values instead of fitted,
        for data that cannot determine them (e.g. ``{"smoothing_g": 1.5}``).
    anchor : array_like, optional
        The values the bounds span a factor :data:`K_BOUND_FACTOR` around (default:
        ``start``).  A fit repeated from its own last result keeps the first start's
        anchor: bounds re-centred on each result let a constant the data hardly
        determine walk ×10³ per round (the sport damper with a cavity: the compression
        port restriction from 10¹² to 10⁻⁷ in seven rounds).
    """
    start = start_values(q, dp_measured, nu_m2_s) if start is None else np.asarray(start, float)
    start = start.copy()
    held = np.zeros(len(NAMES), bool)
    for name, value in (fixed or {}).items():
        if name not in NAMES:
            raise IdentificationError(f"unknown valve parameter {name!r} to fix "
                                      f"(one of {', '.join(NAMES)})")
        value = float(value)
        if not (np.isfinite(value) and value > 0):
            raise IdentificationError(f"fixed valve parameter {name} must be a positive number, "
                                      f"got {value!r}")
        start[NAMES.index(name)] = value
        held[NAMES.index(name)] = True
    w = area_m2 * (np.ones_like(q) if weights is None else np.asarray(weights, float))

    scale_n = float(np.sqrt(np.mean((area_m2 * dp_measured) ** 2)))

    def residual(theta: np.ndarray) -> tuple[np.ndarray, Jacobian]:
        r = w * (pressure_drop_array(q, theta, nu_m2_s, form) - dp_measured)
        # penalty row: the eq 29 extension must not fall below zero at Q = 0
        excess, grad = extension_intercept_excess(theta, nu_m2_s)
        active = excess > 0
        r_pen = MONOTONIC_PENALTY * scale_n * (excess if active else 0.0)
        jac_pen = MONOTONIC_PENALTY * scale_n * (grad if active else np.zeros(grad.size))

        def jacobian() -> np.ndarray:
            # (on demand: about 1.4× the residual's cost)
            jac = w[:, None] * pressure_drop_jacobian(q, theta, nu_m2_s, form)
            return np.vstack((jac, jac_pen))

        return np.append(r, r_pen), jacobian

    # a held value is its own centre (it may lie outside the anchor's bounds)
    centre = start if anchor is None else np.where(held, start, np.asarray(anchor, float))
    lower = np.concatenate((centre[:4] / K_BOUND_FACTOR, [G_MIN]))
    upper = np.concatenate((centre[:4] * K_BOUND_FACTOR, [G_MAX]))
    start[:4] = np.clip(start[:4], lower[:4], upper[:4])
    return fit(residual, NAMES, start, (True,) * 5, lower, upper, area_m2 * dp_measured,
               held, 1)
