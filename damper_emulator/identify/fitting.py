"""Least-squares fitting with log-scaled parameters and fit statistics (eqs 33–35).

A thin layer over :func:`scipy.optimize.least_squares`: the caller supplies residuals and
their exact Jacobian with respect to the parameters (or a function that computes it: then
only at the points the solver asks for it, not at the trial points it rejects); this
module works in ``log θ`` for positive parameters (so that constants spanning decades are
scaled alike), applies bounds, and returns the fit metrics of the paper (eqs 33–35) with
standard errors and correlations from the Jacobian at the optimum.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeAlias

import numpy as np
from scipy.optimize import least_squares

from damper_emulator.errors import UserError

#: A Jacobian, or the function that computes it on demand (an expensive one: the solver
#: needs it only at the points it accepts).
Jacobian: TypeAlias = "np.ndarray | Callable[[], np.ndarray]"
#: ``θ -> (r, ∂r/∂θ)``: the residual function a fit takes
ResidualFunction: TypeAlias = Callable[[np.ndarray], "tuple[np.ndarray, Jacobian]"]


def _jacobian(jac: Jacobian) -> np.ndarray:
    return jac() if callable(jac) else jac


@dataclass(frozen=True)
class FitResult:
    """Outcome of one least-squares fit.

    Attributes
    ----------
    names : tuple of str
    values : ndarray
        Fitted parameters (natural scale).
    std_errors : ndarray
        One-sigma standard errors (natural scale), from ``s² (JᵀJ)⁻¹``.
    correlation : ndarray, shape (p, p)
    cost : float
        Eq 33, ``C = Σ (U_model − U_measured)²`` [N²].
    rms : float
        Eq 34, ``C_RMS = √(C/N)`` [N].
    relative_rms : float
        Eq 35, ``C_RMS / U_measured,RMS``.
    samples : int
    nfev : int
        Residual evaluations used.
    """

    names: tuple[str, ...]
    values: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    cost: float
    rms: float
    relative_rms: float
    samples: int
    nfev: int
    #: names of the parameters held at their start values
    fixed: tuple[str, ...] = ()
    #: names of the parameters that ended on a bound (not determined by the data; their
    #: standard errors are then not meaningful)
    at_bound: tuple[str, ...] = ()

    def as_dict(self) -> dict[str, Any]:
        return {
            "parameters": {n: float(v) for n, v in zip(self.names, self.values)},
            "std_errors": {n: float(s) for n, s in zip(self.names, self.std_errors)},
            "relative_std_errors": {n: float(s / abs(v)) if v else None
                                    for n, s, v in zip(self.names, self.std_errors,
                                                       self.values)},
            "correlation": np.round(self.correlation, 4).tolist(),
            "cost_N2": self.cost, "rms_N": self.rms, "relative_rms": self.relative_rms,
            "samples": self.samples, "evaluations": self.nfev,
            "fixed": list(self.fixed),
            "at_bound": list(self.at_bound),
        }


def fit(residual_and_jacobian: ResidualFunction, names: Sequence[str], start: np.ndarray,
        log_scaled: Sequence[bool] | np.ndarray, lower: np.ndarray, upper: np.ndarray,
        measured: np.ndarray, fixed: Sequence[bool] | np.ndarray | None = None,
        penalty_rows: int = 0) -> FitResult:
    """Minimise ``Σ r(θ)²`` from ``start`` within ``[lower, upper]`` (natural scale).

    Parameters
    ----------
    residual_and_jacobian : callable
        ``θ -> (r, ∂r/∂θ)`` with ``r`` shape (n,) [N] and the Jacobian shape (n, p), both in
        natural parameter scale (the change to ``log θ`` is applied here); the Jacobian
        may be a function of no arguments that returns it, called only when needed.
    names : sequence of str
    start, lower, upper : ndarray, shape (p,)
    log_scaled : sequence of bool
        Fit ``log θ`` for these parameters (they must be positive).
    measured : ndarray
        The measured values the residuals refer to (for eq 35).
    fixed : sequence of bool, optional
        Hold these parameters at their start values (their standard errors and
        correlations are reported as 0).
    penalty_rows : int
        The last ``penalty_rows`` residuals are constraint penalties (zero where the
        constraint holds): minimised with the rest, left out of the fit statistics.
    """
    start = np.asarray(start, dtype=float)
    free = (np.ones(start.size, bool) if fixed is None
            else ~np.asarray(fixed, dtype=bool))
    if not free.any():
        raise UserError("every parameter is fixed: nothing to fit")
    if not free.all():
        return _fit_subset(residual_and_jacobian, names, start, log_scaled, lower, upper,
                           measured, free, penalty_rows)
    log_mask = np.asarray(log_scaled, dtype=bool)

    def to_u(theta: np.ndarray) -> np.ndarray:
        return np.where(log_mask, np.log(np.where(log_mask, theta, 1.0)), theta)

    def to_theta(u: np.ndarray) -> np.ndarray:
        return np.where(log_mask, np.exp(u), u)

    # the last point: its residual, and its Jacobian once asked for
    cache: dict[bytes, list[Any]] = {}

    def point(u: np.ndarray) -> list[Any]:
        key = u.tobytes()
        if key not in cache:
            cache.clear()
            theta = to_theta(u)
            r, jac = residual_and_jacobian(theta)
            cache[key] = [r, jac, theta, None]
        return cache[key]

    def evaluate(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        entry = point(u)
        if entry[3] is None:  # d/d(log θ) = θ d/dθ
            entry[3] = _jacobian(entry[1]) * np.where(log_mask, entry[2], 1.0)
        return entry[0], entry[3]

    lo, hi = to_u(np.asarray(lower, float)), to_u(np.asarray(upper, float))
    u0 = np.clip(to_u(start), lo + 1e-12 * (hi - lo), hi - 1e-12 * (hi - lo))
    sol = least_squares(lambda u: point(u)[0], u0, jac=lambda u: evaluate(u)[1],
                        bounds=(lo, hi), method="trf", x_scale="jac", xtol=1e-12,
                        ftol=1e-12, gtol=1e-12, max_nfev=500)
    theta = to_theta(sol.x)
    r, jac_u = evaluate(sol.x)
    if penalty_rows:
        r, jac_u = r[:-penalty_rows], jac_u[:-penalty_rows]
    n, p = jac_u.shape
    cost = float(np.sum(r ** 2))
    dof = max(n - p, 1)
    cov_u = np.linalg.pinv(jac_u.T @ jac_u) * cost / dof
    sd_u = np.sqrt(np.clip(np.diag(cov_u), 0.0, None))
    std = np.where(log_mask, theta * sd_u, sd_u)  # first order: σ_θ = θ σ_logθ
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_u / np.outer(sd_u, sd_u)
    corr = np.nan_to_num(corr)
    rms = float(np.sqrt(cost / n))
    meas_rms = float(np.sqrt(np.mean(np.asarray(measured, float) ** 2)))
    at_bound = tuple(name for name, a in zip(names, sol.active_mask) if a != 0)
    return FitResult(tuple(names), theta, std, corr, cost, rms,
                     rms / meas_rms if meas_rms > 0 else float("inf"), n, int(sol.nfev),
                     (), at_bound)


def _fit_subset(residual_and_jacobian: ResidualFunction, names: Sequence[str],
                start: np.ndarray, log_scaled: Sequence[bool] | np.ndarray,
                lower: np.ndarray, upper: np.ndarray, measured: np.ndarray,
                free: np.ndarray, penalty_rows: int) -> FitResult:
    """:func:`fit` over the free parameters only, reported over all of them."""
    def residual(theta_free: np.ndarray) -> tuple[np.ndarray, Jacobian]:
        theta = start.copy()
        theta[free] = theta_free
        r, jac = residual_and_jacobian(theta)
        return r, lambda: _jacobian(jac)[:, free]

    sub = fit(residual, [n for n, f in zip(names, free) if f], start[free],
              np.asarray(log_scaled, bool)[free], np.asarray(lower, float)[free],
              np.asarray(upper, float)[free], measured, None, penalty_rows)
    values, std = start.copy(), np.zeros(start.size)
    values[free], std[free] = sub.values, sub.std_errors
    corr = np.zeros((start.size, start.size))
    corr[np.ix_(free, free)] = sub.correlation
    return FitResult(tuple(names), values, std, corr, sub.cost, sub.rms, sub.relative_rms,
                     sub.samples, sub.nfev, tuple(n for n, f in zip(names, free) if not f),
                     sub.at_bound)
