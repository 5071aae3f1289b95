"""The twin keeps learning the specimen during the ride: a bounded recursive least-squares
correction of its force map.

The twin learned before the ride (:mod:`ride_sim.hybrid.learn`) is the specimen as it was
then.  Over a ride the specimen warms: its oil thins (the valves' force falls), its gas
charge's pressure rises (the static force moves).  The host corrects the twin's force
``F`` (stepped on the measured motion ``x``, ``v``) as::

    F̂ = F_s + θ₀ + θ₁ (F − F_s) [v < 0] + θ₂ (F − F_s) [v ≥ 0] + θ₃ v + θ₄ x + θ₅ sign(v)

``F_s`` the twin's force at rest at the static position.  ``θ = (0, 1, 1, 0, 0, 0)`` is the
twin as learned; each term reads as a change of the damper's physics: a static force
(``θ₀``, the gas charge), the valves' force in compression and rebound (``θ₁``, ``θ₂``, the
oil's viscosity), a linear damping (``θ₃``), a spring rate (``θ₄``, the gas spring) and a
friction (``θ₅``).

Each sample whose measurement came updates ``θ`` by recursive least squares with
exponential forgetting (its memory ``learn.online_window_s``); the force used
is the twin's prediction before its own sample updates it, so the residual reported is a
prediction's.  Two guards keep the estimate physical where the motion does not excite
every term (a smooth stretch of road): the covariance never grows past its start (no
wind-up), and the valves' gains stay within ``1 ± learn.online_gain_bound``.

The compensator's prediction uses the corrected force (:func:`mapped_force`), and the
small-gain margin of its force path is recomputed for the corrected twin
(:meth:`OnlineTwin.slope`): the map's steepest slope is at most
``max(θ₁, θ₂) c + max(θ₃, 0)``, ``c`` the twin's own (:func:`steepest_slope`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.jit import kernel
from ride_sim.hybrid.params import LearnParams

_Vec = NDArray[np.float64]

#: The map's terms, in ``θ``'s order (``hybrid.json``'s ``twin.online.terms``), each with
#: its unit.
TERMS = (("static_force_n", "N"), ("compression_gain", "-"), ("rebound_gain", "-"),
         ("damping_ns_m", "N s/m"), ("stiffness_n_m", "N/m"), ("friction_n", "N"))
#: ``θ`` of the twin as learned.
IDENTITY = (0.0, 1.0, 1.0, 0.0, 0.0, 0.0)
#: The spread of ``θ`` the estimate starts from, with the force noise it assumes: a
#: static force and a friction of ``FORCE_SPREAD_N``, gains of ``GAIN_SPREAD``, a damping
#: of ``GAIN_SPREAD`` times the twin's steepest slope, a spring rate that moves
#: ``FORCE_SPREAD_N`` over ``STROKE_SPREAD_M``.  Forgetting makes the estimate
#: independent of them after a window (tried: spreads 2× and 6× gave the same ``θ`` to
#: three digits); they set only how far the first samples move it.
FORCE_SPREAD_N = 50.0
GAIN_SPREAD = 0.3
STROKE_SPREAD_M = 0.01


@kernel
def regressors(dynamic_n: float, x: float, v: float
               ) -> tuple[float, float, float, float, float, float]:
    """What each term of ``θ`` multiplies (the module docstring's map, :data:`TERMS`' order)
    at the motion ``x``, ``v``, the twin's force being ``dynamic_n`` from ``F_s``."""
    sign = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    compression = dynamic_n if v < 0.0 else 0.0
    return (1.0, compression, dynamic_n - compression, v, x, sign)


@kernel
def mapped_force(theta: _Vec, static_n: float, force_n: float, x: float, v: float
                 ) -> float:
    """The twin's force ``force_n`` at the motion ``x``, ``v`` through the map ``theta``
    (the module docstring's ``F̂``; ``F_s`` = ``static_n``)."""
    phi = regressors(force_n - static_n, x, v)
    out: float = static_n
    for i in range(len(phi)):
        out += theta[i] * phi[i]
    return out


@kernel
def rls_update(theta: _Vec, p: _Vec, p_start: _Vec, lo: _Vec, hi: _Vec, phi: _Vec,
               y: float, forget: float, px: _Vec) -> None:
    """One recursive least-squares step of ``y ≈ φ·θ`` with forgetting factor ``forget``,
    in place: ``P`` scaled back to its start's mean variance where it has grown past it
    (``p_start`` the start's diagonal), ``θ`` clamped to ``[lo, hi]``; ``px`` is scratch
    of ``θ``'s size."""
    n = theta.size
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += p[i, j] * phi[j]
        px[i] = acc
    denom = forget
    err = y
    for i in range(n):
        denom += phi[i] * px[i]
        err -= phi[i] * theta[i]
    for i in range(n):
        theta[i] += px[i] / denom * err
    growth = 0.0
    for i in range(n):
        for j in range(n):
            p[i, j] = (p[i, j] - px[i] * px[j] / denom) / forget
        growth += p[i, i] / p_start[i]
    growth /= n
    if growth > 1.0:
        for i in range(n):
            for j in range(n):
                p[i, j] /= growth
    for i in range(n):
        theta[i] = min(max(theta[i], lo[i]), hi[i])


class OnlineTwin:
    """The twin's online correction (see the module docstring).

    Parameters
    ----------
    params : LearnParams
        ``online``, ``online_window_s``, ``online_gain_bound``.
    static_n : float
        The twin's force at rest at the static position ``F_s`` [N].
    slope_ns_m : float
        The twin's steepest force–velocity slope ``c`` [N s/m].
    dt_s : float
        The host's cycle [s].
    """

    def __init__(self, params: LearnParams, static_n: float, slope_ns_m: float,
                 dt_s: float) -> None:
        self.enabled = bool(params.online)
        self.static_n = float(static_n)
        self.slope_ns_m = float(slope_ns_m)
        #: the map's coefficients (the compensator reads them in place)
        self.theta = np.array(IDENTITY)
        spread = np.array([FORCE_SPREAD_N, GAIN_SPREAD, GAIN_SPREAD,
                           GAIN_SPREAD * max(slope_ns_m, 1.0),
                           FORCE_SPREAD_N / STROKE_SPREAD_M, FORCE_SPREAD_N])
        self._p_start = spread ** 2 / FORCE_SPREAD_N ** 2
        self._p = np.diag(self._p_start)
        bound = params.online_gain_bound
        self._lo = np.full(len(TERMS), -math.inf)
        self._hi = np.full(len(TERMS), math.inf)
        self._lo[1:3], self._hi[1:3] = 1.0 - bound, 1.0 + bound
        self._forget = 1.0 - dt_s / params.online_window_s
        self._phi = np.zeros(len(TERMS))
        self._px = np.zeros(len(TERMS))
        self.updates = 0

    def force(self, force_n: float, x: float, v: float) -> float:
        """The corrected force of the twin's ``force_n`` at the motion ``x``, ``v``."""
        return float(mapped_force(self.theta, self.static_n, force_n, x, v))

    def update(self, force_n: float, x: float, v: float, measured_n: float) -> None:
        """Learn from one sample: the twin's force at the measured motion and the force
        measured there (a no-op when disabled)."""
        if not self.enabled:
            return
        self._phi[:] = regressors(force_n - self.static_n, x, v)
        rls_update(self.theta, self._p, self._p_start, self._lo, self._hi, self._phi,
                   measured_n - self.static_n, self._forget, self._px)
        self.updates += 1

    def slope(self) -> float:
        """The corrected twin's steepest slope, at most ``max(θ₁, θ₂) c + max(θ₃, 0)``
        [N s/m]."""
        t = self.theta
        return float(max(t[1], t[2]) * self.slope_ns_m + max(t[3], 0.0))

    def terms(self) -> dict[str, float]:
        """``θ`` by term name (:data:`TERMS`)."""
        return {name: float(value) for (name, _), value in zip(TERMS, self.theta)}

    def warm_up(self) -> None:
        """Load or compile the kernels, on copies: the estimate stays as it is."""
        self.force(self.static_n, 0.0, 0.0)
        self._phi[:] = regressors(0.0, 0.0, 0.1)
        rls_update(self.theta.copy(), self._p.copy(), self._p_start, self._lo, self._hi,
                   self._phi, 0.0, self._forget, self._px)
