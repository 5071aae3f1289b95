"""The discovered term: a force the diagnosis found in what the library of
effects left, as a sum of coefficients times features of the motion and of the model's
own states, evaluated in the compressible model's one compiled step.

The features (one place for the real-time step, the batch simulation and the discovery's
dictionary, :mod:`damper_emulator.diagnose.discovery`) are, per sample, with the stroke
``x``, the velocity ``ẋ``, the smooth sign ``s = tanh(ẋ / v_s)``, the chamber pressures
``p_r``, ``p_c`` and the model's force ``F`` *without* the term:

- ``TERM_ACCELERATION``: ``ẍ`` (:func:`acceleration`) [kg];
- ``TERM_VELOCITY``, ``TERM_VELOCITY_SQ``, ``TERM_VELOCITY_CUBE``: ``ẋ``, ``ẋ |ẋ|``,
  ``ẋ³`` [N·s/m, N·s²/m², N·s³/m³];
- ``TERM_SIGN``: ``s`` [N];
- ``TERM_STROKE``, ``TERM_STROKE_SQ``, ``TERM_STROKE_CUBE``: ``x``, ``x²``, ``x³``
  [N/m, N/m², N/m³];
- ``TERM_STROKE_VEL``, ``TERM_STROKE_SQ_VEL``: ``x ẋ``, ``x² ẋ`` [N·s/m², N·s/m³];
- ``TERM_STROKE_SIGN``, ``TERM_STROKE_SQ_SIGN``, ``TERM_ABS_STROKE_SIGN``: ``x s``,
  ``x² s``, ``|x| s`` [N/m, N/m², N/m];
- ``TERM_P_COM_SIGN``, ``TERM_P_REB_SIGN``, ``TERM_P_DROP``: ``p_c s``, ``p_r s``,
  ``p_r − p_c`` [m²];
- ``TERM_ENERGY``: ``E F``, ``E`` the energy dissipated so far [1/J];
- ``TERM_TEMPERATURE``: ``(T − T_ref) F``, ``T`` measured (none: 0) [1/K];
- ``TERM_PROFILE``: ``exp(−(x − c)² / (2 w²)) ẋ`` [N·s/m];
- ``TERM_LAG``: ``y − F``, ``τ ẏ = F − y`` [-].

(the coefficient's unit in brackets).

The term is added to the damper's force at the rod; it does not feed back into the
chamber pressures (the discovery fits it as an additive force).  The acceleration is the
derivative of the velocity input by the three-point backward formula of variable steps
(exact for a quadratic; a one-sided difference has half a sample's lag, which on a 6 kg
inertia at 12 Hz and 1 kHz leaves 4 % of its force); the energy integrates ``F ẋ`` by the
rectangle rule; the lag is exact for a force linear between samples.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.jit import kernel

(TERM_ACCELERATION, TERM_VELOCITY, TERM_VELOCITY_SQ, TERM_VELOCITY_CUBE, TERM_SIGN,
 TERM_STROKE, TERM_STROKE_SQ, TERM_STROKE_CUBE, TERM_STROKE_VEL, TERM_STROKE_SQ_VEL,
 TERM_STROKE_SIGN, TERM_STROKE_SQ_SIGN, TERM_ABS_STROKE_SIGN, TERM_P_COM_SIGN,
 TERM_P_REB_SIGN, TERM_P_DROP, TERM_ENERGY, TERM_TEMPERATURE, TERM_PROFILE, TERM_LAG,
 N_TERMS) = range(21)

#: The coefficient's field of ``damper.extensions.discovered_term``
#: (:class:`damper_emulator.params.DiscoveredTermParams`) of each feature, by index.
TERM_FIELDS = (
    "acceleration_kg", "velocity_n_s_m", "velocity_squared_n_s2_m2",
    "velocity_cubed_n_s3_m3", "smooth_sign_n", "stroke_n_m", "stroke_squared_n_m2",
    "stroke_cubed_n_m3", "stroke_velocity_n_s_m2", "stroke_squared_velocity_n_s_m3",
    "stroke_sign_n_m", "stroke_squared_sign_n_m2", "abs_stroke_sign_n_m",
    "compression_pressure_sign_m2",
    "rebound_pressure_sign_m2", "pressure_drop_m2", "energy_force_per_j",
    "temperature_force_per_k", "profile_n_s_m", "lag_coefficient")

_Vec = NDArray[np.float64]


@kernel
def acceleration(v: float, v1: float, v2: float, h1: float, h2: float) -> float:
    """``ẍ`` [m/s²] at the velocity ``v`` from the two before (``v1`` ``h1`` seconds
    earlier, ``v2`` ``h2`` before that): the derivative of the parabola through them; with
    ``h2 = 0`` (no second one yet) the one-sided difference, with ``h1 = 0`` zero."""
    if h1 <= 0.0:
        return 0.0
    if h2 <= 0.0:
        return (v - v1) / h1
    return (v * (2.0 * h1 + h2) / (h1 * (h1 + h2)) - v1 * (h1 + h2) / (h1 * h2)
            + v2 * h1 / (h2 * (h1 + h2)))


@kernel
def lag_update(y: float, f_old: float, f_new: float, h: float, tau: float) -> float:
    """First-order lag ``τ ẏ = F − y`` after ``h`` [s], exact for ``F`` linear from
    ``f_old`` to ``f_new``: ``F₁ + (y − F₀) e − (F₁ − F₀) τ/h (1 − e)``, ``e = exp(−h/τ)``."""
    if h <= 0.0:
        return y
    e = math.exp(-h / tau)
    return f_new + (y - f_old) * e - (f_new - f_old) * tau / h * (1.0 - e)


@kernel
def advance(v: float, v1: float, v2: float, h1: float, h2: float, energy: float,
            lag: float, f_old: float, force: float, tau: float
            ) -> tuple[float, float, float]:
    """The states of the term at a sample ``h1`` [s] after the last, ``(ẍ, E, y)``: the
    acceleration (:func:`acceleration`, from the velocities ``v``, ``v1``, ``v2`` and the
    steps ``h1``, ``h2``), the energy ``E`` grown by ``F ẋ h1`` and the lag ``y``
    advanced from ``f_old`` to the force ``F`` (:func:`lag_update`); ``h1 = 0``, a
    settled start: ``(0, E, F)``."""
    if h1 <= 0.0:
        return 0.0, energy, force
    return (acceleration(v, v1, v2, h1, h2), energy + force * v * h1,
            lag_update(lag, f_old, force, h1, tau))


@kernel
def profile(x: float, v: float, centre: float, width: float) -> float:
    """``exp(−(x − c)² / (2 w²)) ẋ``: damping over a part of the stroke."""
    r = (x - centre) / width
    return math.exp(-0.5 * r * r) * v


@kernel
def features(out: _Vec, x: float, v: float, a: float, temperature: float, energy: float,
             p_reb: float, p_com: float, force: float, lag: float, v_sign: float,
             t_ref: float, centre: float, width: float) -> None:
    """Write the :data:`N_TERMS` features (module table) of one sample into ``out``
    (``temperature`` NaN: no measured temperature, its feature 0; ``width`` 0: no
    profile, 0)."""
    s = math.tanh(v / v_sign)
    out[TERM_ACCELERATION] = a
    out[TERM_VELOCITY] = v
    out[TERM_VELOCITY_SQ] = v * abs(v)
    out[TERM_VELOCITY_CUBE] = v * v * v
    out[TERM_SIGN] = s
    out[TERM_STROKE] = x
    out[TERM_STROKE_SQ] = x * x
    out[TERM_STROKE_CUBE] = x * x * x
    out[TERM_STROKE_VEL] = x * v
    out[TERM_STROKE_SQ_VEL] = x * x * v
    out[TERM_STROKE_SIGN] = x * s
    out[TERM_STROKE_SQ_SIGN] = x * x * s
    out[TERM_ABS_STROKE_SIGN] = abs(x) * s
    out[TERM_P_COM_SIGN] = p_com * s
    out[TERM_P_REB_SIGN] = p_reb * s
    out[TERM_P_DROP] = p_reb - p_com
    out[TERM_ENERGY] = energy * force
    out[TERM_TEMPERATURE] = ((temperature - t_ref) * force if math.isfinite(temperature)
                             else 0.0)
    out[TERM_PROFILE] = profile(x, v, centre, width) if width > 0.0 else 0.0
    out[TERM_LAG] = lag - force


@kernel
def feature_history(t: _Vec, x: _Vec, v: _Vec, temperature: _Vec, force: _Vec,
                    p_reb: _Vec, p_com: _Vec, v_sign: float, t_ref: float, centre: float,
                    width: float, tau: float, out: NDArray[np.float64]) -> None:
    """The features of every sample of a record (``out``: ``(n, N_TERMS)``) from its
    motion and the model's states and force without the term, as the compiled step
    evaluates them sample by sample (the acceleration, the energy and the lag integrated
    the same way, from rest at the first sample)."""
    energy = 0.0
    lag = 0.0
    for i in range(t.size):
        # the first sample is a settled start (no step before it), the second has one
        j1, j2 = max(i - 1, 0), max(i - 2, 0)
        a, energy, lag = advance(v[i], v[j1], v[j2], t[i] - t[j1], t[j1] - t[j2], energy,
                                 lag, force[j1], force[i], tau)
        features(out[i], x[i], v[i], a, temperature[i], energy, p_reb[i], p_com[i],
                 force[i], lag, v_sign, t_ref, centre, width)


@kernel
def profile_history(x: _Vec, v: _Vec, centre: float, width: float, out: _Vec) -> None:
    """The zone feature ``exp(−(x − c)² / (2 w²)) ẋ`` of every sample into ``out``."""
    for i in range(x.size):
        out[i] = profile(x[i], v[i], centre, width)


@kernel
def lag_history(t: _Vec, force: _Vec, tau: float, out: _Vec) -> None:
    """The lag feature ``y − F`` (``τ ẏ = F − y`` from ``y = F`` at the first sample) of
    every sample into ``out``."""
    lag = force[0]
    out[0] = 0.0
    for i in range(1, t.size):
        lag = lag_update(lag, force[i - 1], force[i], t[i] - t[i - 1], tau)
        out[i] = lag - force[i]
