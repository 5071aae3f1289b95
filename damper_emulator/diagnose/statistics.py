"""The statistics a diagnosis judges by: a residual's effective number of independent
samples (an AR(1) residual's lag-1 autocorrelation), the effective BIC of a change, and
least squares with σ inflated for that autocorrelation.

A dyno record's residual is never white: 40,000 samples of a residual correlated over
milliseconds are not 40,000 pieces of evidence.  Every figure here takes each file's
samples as ``n_eff = n (1 − ρ)/(1 + ρ)``, ``ρ`` its lag-1 autocorrelation.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

__all__ = ["MAX_RHO", "bic_gain", "bic_term", "delta_bic", "effective_samples",
           "fit_columns", "lag1"]

#: lag-1 autocorrelation is clipped to this in the effective sample size
MAX_RHO = 0.999


def effective_samples(n: int, rho: float) -> float:
    """The number of independent samples ``n (1 − ρ)/(1 + ρ)`` of ``n`` samples of an AR(1)
    series of lag-1 autocorrelation ``ρ``."""
    return n * (1.0 - rho) / (1.0 + rho)


def bic_term(n: int, rho: float, ms_after: float, ms_before: float) -> float:
    """One file's change of the effective BIC from mean square ``ms_before`` to
    ``ms_after`` (no parameter counted): ``n_eff ln(ms_after / ms_before)``, ``n_eff`` of
    ``n`` samples with the lag-1 autocorrelation ``rho`` of the residual after
    (:func:`effective_samples`); negative when the residual got smaller."""
    return effective_samples(n, rho) * math.log(max(ms_after, 1e-300)
                                                / max(ms_before, 1e-300))


def delta_bic(files: Iterable[tuple[int, float, float, float]], k: int) -> float:
    """The effective ΔBIC of a fit with ``k`` more parameters than the one it is compared
    with, per file ``(n, rho, ms_after, ms_before)``: the sum of :func:`bic_term` plus
    ``k ln(Σ n_eff)`` (:func:`effective_samples`; at least ``ln 2``)."""
    dbic, n_eff = 0.0, 0.0
    for n, rho, ms_after, ms_before in files:
        dbic += bic_term(n, rho, ms_after, ms_before)
        n_eff += effective_samples(n, rho)
    return dbic + k * math.log(max(n_eff, 2.0))


def bic_gain(before: Sequence[np.ndarray], after: Sequence[np.ndarray]) -> float:
    """How much lower the effective BIC of residuals ``after`` is than of ``before`` (the
    same files, one array each): ``−Σ_f`` :func:`bic_term`."""
    return -sum(bic_term(r1.size, lag1(r1), float(np.dot(r1, r1)), float(np.dot(r0, r0)))
                for r0, r1 in zip(before, after))


def lag1(r: np.ndarray) -> float:
    """Lag-1 autocorrelation of ``r`` (mean removed), clipped to ``[0, MAX_RHO]``."""
    r = r - r.mean()
    den = float(np.dot(r, r))
    if r.size < 3 or den <= 0.0:
        return 0.0
    return min(max(float(np.dot(r[1:], r[:-1])) / den, 0.0), MAX_RHO)



def fit_columns(a: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares of ``y`` on the columns of ``a``: ``(coefficients, their 1σ, the
    residual y − a c)``, the σ from ``s² (AᵀA)⁻¹`` inflated by ``(1 + ρ)/(1 − ρ)`` for the
    residual's lag-1 autocorrelation ρ (as the joint fits' are); infinite where ``AᵀA``
    is singular."""
    coef: np.ndarray = np.linalg.lstsq(a, y, rcond=None)[0]
    r: np.ndarray = y - a @ coef
    rho = lag1(r)
    s2 = float(np.dot(r, r)) / max(r.size - a.shape[1], 1) * (1.0 + rho) / (1.0 - rho)
    try:
        sd = np.sqrt(np.maximum(np.diag(np.linalg.inv(a.T @ a)) * s2, 0.0))
    except np.linalg.LinAlgError:
        sd = np.full(a.shape[1], np.inf)
    return coef, sd, r
