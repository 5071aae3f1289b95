"""Valve pressure–flow characteristic of one piston-valve direction.

Simms & Crolla (SAE 2002-01-0319), section 2.2: a port restriction in series with a leak
restriction in parallel with a preloaded blow-off valve.  All functions take the flow
*magnitude* ``q_m3_s >= 0`` through the valve and return the pressure drop magnitude [Pa];
the sign convention (rebound / compression) is applied by the callers.

The scalar kernels are compiled with numba so that the real-time stepper, the batch
simulator and the identification share one implementation.  ``pressure_drop_array`` maps
the scalar kernel over a numpy array.

Valve parameters are passed as a 5-tuple ``(k_leak, k_port, k_spring, preload_pa, g)``
in the paper's units: ``K_leak``, ``K_port`` [kg/m^(27/4)], ``K_spring``
[kg^(3/2)/(s^2 m^(9/2))], ``Δp0`` [Pa], smoothing exponent ``G`` [-].
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.errors import UserError
from damper_emulator.model.jit import batch_kernel, kernel

#: Exponent of the Reybrouck power law ``Δp ∝ Q^(7/4)`` (eqs 8, 9).
FLOW_EXPONENT = 7.0 / 4.0

#: Valve forms: the paper's explicit Taylor–Cardano solution (eq 22) or an exact root
#: solve of eq 19.
VALVE_FORMS = ("cardano", "exact")
FORM_CARDANO = 0
FORM_EXACT = 1

# Bisection/Newton iterations of the exact solve of eq 19: enough to reach double precision
# from a bracket of relative width one (2^-60 ~ 1e-18).
_EXACT_ITERATIONS = 60

#: A kernel's number: real, or complex for the complex-step derivatives (the real part
#: carries the value).
_Num = TypeVar("_Num", float, complex)
#: the blow-off coefficients ``(B0, B1, B2, B3)`` (or their derivatives in one parameter)
_Blow = tuple[float, float, float, float]


@kernel
def blow_off_coefficients(k_leak: _Num, k_spring: _Num, preload_pa: _Num,
                          nu_m2_s: float) -> tuple[_Num, _Num, _Num, _Num]:
    """Taylor coefficients of the open-valve flow about the blow-off point.

    Eqs 23 and 40–43: ``B0 = Q_leak,bo = (Δp0 / (K_leak ν^¼))^(4/7)`` and
    ``Q_tot ≈ B0 + B1 y + B2 y² + B3 y³`` with ``y = Q_leak − B0``.

    Returns
    -------
    b0, b1, b2, b3 : float
        ``B0`` [m³/s], ``B1`` [-], ``B2`` [s/m³], ``B3`` [s²/m⁶].
    """
    kl = k_leak * nu_m2_s ** 0.25
    b0 = (preload_pa / kl) ** (1.0 / FLOW_EXPONENT)
    c = preload_pa ** 1.5 / k_spring
    b1 = 1.0 + 7.0 * c / (4.0 * b0)
    b2 = 35.0 * c / (16.0 * b0 * b0)
    b3 = 217.0 * c / (512.0 * b0 * b0 * b0)
    return b0, b1, b2, b3


@kernel
def _abs(a: _Num) -> _Num:
    """``|a|`` by the sign of the real part: the identity for real numbers, and for a
    complex-step argument ``a + ih`` it keeps the derivative (``abs`` would not)."""
    return a if a.real >= 0.0 else -a


@kernel
def _cbrt(a: _Num) -> _Num:
    """Real cube root (sign by the real part; complex-step safe)."""
    root: _Num = a ** (1.0 / 3.0) if a.real >= 0.0 else -((-a) ** (1.0 / 3.0))
    return root


@kernel
def leak_flow_cardano(q_tot: _Num, b0: _Num, b1: _Num, b2: _Num, b3: _Num) -> _Num:
    """Leak flow of the open valve by the paper's explicit cubic solution (eqs 44–46, 22).

    Where ``D3 < 0`` (three real roots) the principal complex cube roots of eq 22 are
    evaluated in their equivalent trigonometric form: ``2 √(−D1/3) cos(φ/3)`` with
    ``cos φ = (−D2/2) / √(−D1³/27)`` (the imaginary parts cancel).
    """
    d1 = (3.0 * b1 * b3 - b2 * b2) / (3.0 * b3 * b3)  # eq 44
    # (integer powers written as products: a complex power of a negative number goes
    # through the polar form and spoils complex-step derivatives)
    d2 = (2.0 * b2 * b2 * b2 - 9.0 * b1 * b2 * b3 + 27.0 * (b0 - q_tot) * b3 * b3) / (
        27.0 * b3 * b3 * b3
    )  # eq 45
    d3 = d2 * d2 / 4.0 + d1 * d1 * d1 / 27.0  # eq 46
    if d3.real >= 0.0:
        s = d3 ** 0.5
        t = _cbrt(-d2 / 2.0 + s) + _cbrt(-d2 / 2.0 - s)
    else:
        r = (-d1 / 3.0) ** 0.5
        c = (-d2 / 2.0) / (r * r * r)
        if c.real > 1.0:
            c = c - (c.real - 1.0)
        elif c.real < -1.0:
            c = c - (c.real + 1.0)
        t = 2.0 * r * np.cos(np.arccos(c) / 3.0)
    q_leak: _Num = b0 - b2 / (3.0 * b3) + t  # eq 22
    return q_leak


@kernel
def total_flow_open(q_leak: _Num, k_leak: _Num, k_spring: _Num, preload_pa: _Num,
                    nu_m2_s: float) -> _Num:
    """Total flow of the open valve as a function of the leak flow, eq 19."""
    dp_leak = k_leak * nu_m2_s ** 0.25 * q_leak ** FLOW_EXPONENT
    q_tot: _Num = q_leak + (dp_leak - preload_pa) * dp_leak ** 0.5 / k_spring
    return q_tot


@kernel
def leak_flow_exact(q_tot: _Num, k_leak: _Num, k_spring: _Num, preload_pa: _Num,
                    nu_m2_s: float, b0: _Num) -> _Num:
    """Leak flow of the open valve by an exact root solve of eq 19 (``q_tot >= b0``).

    Eq 19 is increasing in ``Q_leak`` above the blow-off point and ``Q_tot(Q_leak) >=
    Q_leak``, so the root lies in ``[B0, Q_tot]``: bisection to double precision on the
    real parts, then one Newton step with the exact derivative of eq 19, which carries the
    derivatives of a complex-step evaluation through the root.
    """
    b0r = b0.real
    kl, ks, dp0, qt = k_leak.real, k_spring.real, preload_pa.real, q_tot.real
    lo = b0r
    hi = max(qt, b0r)
    for _ in range(_EXACT_ITERATIONS + int(math.log2(1.0 + hi / max(b0r, 1e-300)))):
        mid = 0.5 * (lo + hi)
        if total_flow_open(mid, kl, ks, dp0, nu_m2_s) < qt:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-16 * hi:
            break
    root = 0.5 * (lo + hi)
    p = k_leak * nu_m2_s ** 0.25 * root ** FLOW_EXPONENT
    slope = 1.0 + FLOW_EXPONENT * p / root * (p ** 0.5 + (p - preload_pa) / (2.0 * p ** 0.5)) \
        / k_spring
    q_leak: _Num = root - (total_flow_open(root, k_leak, k_spring, preload_pa, nu_m2_s)
                          - q_tot) / slope
    return q_leak


@kernel
def pressure_drop_closed(q_tot: _Num, k_leak: _Num, k_port: _Num, nu_m2_s: float) -> _Num:
    """Pressure drop with the blow-off valve closed, eq 15."""
    dp: _Num = (k_port + k_leak) * nu_m2_s ** 0.25 * q_tot ** FLOW_EXPONENT
    return dp


@kernel
def low_flow_line(b0: _Num, b1: _Num, k_leak: _Num, k_port: _Num, nu4: float
                  ) -> tuple[_Num, _Num]:
    """``H0`` [Pa] and ``H1`` [Pa s/m³] of the open characteristic's linear extension
    below the blow-off flow, ``Δp = H0 + H1 (Q − B0)`` (eq 29): eq 47 and eq 48 as
    corrected in docs/model.md §2.2 (``nu4`` = ν^¼)."""
    h0 = b0 ** FLOW_EXPONENT * nu4 * (k_leak + k_port)  # eq 47
    h1 = FLOW_EXPONENT * nu4 * b0 ** 0.75 * (k_leak / b1 + k_port)  # eq 48 (corrected)
    return h0, h1


@kernel
def open_constants(k_leak: _Num, k_port: _Num, k_spring: _Num, preload_pa: _Num,
                   nu_m2_s: float) -> tuple[float, _Num, _Num, _Num, _Num, _Num, _Num]:
    """What the open characteristic needs of one valve, whatever the flow: ``(ν^¼, B0,
    B1, B2, B3, H0, H1)`` (:func:`blow_off_coefficients`, :func:`low_flow_line`).
    Computed once per valve by the loops over flows: these powers are half of
    :func:`pressure_drop`'s cost (benchmarks/model_bench.py's model load)."""
    nu4 = nu_m2_s ** 0.25
    b0, b1, b2, b3 = blow_off_coefficients(k_leak, k_spring, preload_pa, nu_m2_s)
    h0, h1 = low_flow_line(b0, b1, k_leak, k_port, nu4)
    return nu4, b0, b1, b2, b3, h0, h1


@kernel
def _open_branch_with(q_tot: _Num, k_leak: _Num, k_port: _Num, k_spring: _Num,
                      preload_pa: _Num, nu_m2_s: float, form: int,
                      const: tuple[float, _Num, _Num, _Num, _Num, _Num, _Num]
                      ) -> tuple[_Num, _Num]:
    """``(Δp, Q_leak)`` of the open branch (:func:`_open_branch`) from the valve's
    :func:`open_constants`."""
    nu4, b0, b1, b2, b3, h0, h1 = const
    if q_tot.real >= b0.real:
        if form == FORM_EXACT:
            q_leak = leak_flow_exact(q_tot, k_leak, k_spring, preload_pa, nu_m2_s, b0)
        else:
            q_leak = leak_flow_cardano(q_tot, b0, b1, b2, b3)
        dp: _Num = nu4 * (k_leak * q_leak ** FLOW_EXPONENT + k_port * q_tot ** FLOW_EXPONENT)
        return dp, q_leak
    dp_low: _Num = h0 + h1 * (q_tot - b0)  # eq 29
    return dp_low, b0


@kernel
def _open_branch(q_tot: _Num, k_leak: _Num, k_port: _Num, k_spring: _Num, preload_pa: _Num,
                 nu_m2_s: float, form: int
                 ) -> tuple[_Num, _Num, _Num, _Num, _Num, _Num]:
    """:func:`pressure_drop_open` with what its derivatives need: ``(Δp, Q_leak, B0, B1,
    B2, B3)``; ``Q_leak`` is ``B0`` below the blow-off flow (the linear extension)."""
    const = open_constants(k_leak, k_port, k_spring, preload_pa, nu_m2_s)
    dp, q_leak = _open_branch_with(q_tot, k_leak, k_port, k_spring, preload_pa, nu_m2_s,
                                   form, const)
    return dp, q_leak, const[1], const[2], const[3], const[4]


@kernel
def pressure_drop_open(q_tot: _Num, k_leak: _Num, k_port: _Num, k_spring: _Num,
                       preload_pa: _Num, nu_m2_s: float, form: int) -> _Num:
    """Pressure drop with the blow-off valve open: eq 27 above the blow-off flow, its
    linear extension eqs 29/47 below it (``H1`` as corrected in docs/model.md §2.2)."""
    dp: _Num = _open_branch(q_tot, k_leak, k_port, k_spring, preload_pa, nu_m2_s, form)[0]
    return dp


@kernel
def smooth_transition(dp_open: _Num, dp_closed: _Num, g: _Num) -> _Num:
    """Smoothed minimum of the two branches, eq 28."""
    if dp_closed.real == 0.0 or dp_open.real == 0.0:
        return dp_open * 0.0
    dp: _Num = dp_open * dp_closed / (_abs(dp_open) ** g + _abs(dp_closed) ** g) ** (1.0 / g)
    return dp


@kernel
def pressure_drop(q_tot: _Num, k_leak: _Num, k_port: _Num, k_spring: _Num, preload_pa: _Num,
                  g: _Num, nu_m2_s: float, form: int) -> _Num:
    """Valve pressure drop magnitude ``Δp(Q)`` [Pa] for a flow magnitude ``q_tot`` [m³/s].

    The smoothed (eq 28) combination of the closed-valve (eq 15) and open-valve
    (eqs 27, 29) characteristics.  ``form`` is ``FORM_CARDANO`` (eq 22 as published) or
    ``FORM_EXACT`` (root of eq 19).
    """
    dp: _Num = pressure_drop_with(q_tot, k_leak, k_port, k_spring, preload_pa, g, nu_m2_s,
                                  form, open_constants(k_leak, k_port, k_spring, preload_pa,
                                                       nu_m2_s))
    return dp


@kernel
def pressure_drop_with(q_tot: _Num, k_leak: _Num, k_port: _Num, k_spring: _Num,
                       preload_pa: _Num, g: _Num, nu_m2_s: float, form: int,
                       const: tuple[float, _Num, _Num, _Num, _Num, _Num, _Num]) -> _Num:
    """:func:`pressure_drop` from the valve's :func:`open_constants` ``const``: a loop over
    flows of one valve computes them once."""
    closed = pressure_drop_closed(q_tot, k_leak, k_port, nu_m2_s)
    opened = _open_branch_with(q_tot, k_leak, k_port, k_spring, preload_pa, nu_m2_s, form,
                               const)[0]
    dp: _Num = smooth_transition(opened, closed, g)
    return dp


@kernel
def _blow_off_derivative(b: _Blow, rel_c: float, rel_b0: float) -> _Blow:
    """Derivatives of the blow-off coefficients ``b`` (:func:`blow_off_coefficients`) in
    one parameter, from the relative derivatives of ``c = Δp0^1.5/K_spring`` and of
    ``B0``: each coefficient is a power law in them (``B1 − 1 ∝ c/B0``, ``B2 ∝ c/B0²``,
    ``B3 ∝ c/B0³``, eqs 40–43)."""
    b0, b1, b2, b3 = b
    return (b0 * rel_b0, (b1 - 1.0) * (rel_c - rel_b0), b2 * (rel_c - 2.0 * rel_b0),
            b3 * (rel_c - 3.0 * rel_b0))


@kernel
def _cubic_root_derivative(y: float, slope: float, d: _Blow) -> float:
    """``dQ_leak`` of the paper's form in one parameter: ``y = Q_leak − B0`` solves
    ``B0 + B1 y + B2 y² + B3 y³ = Q_tot`` (the cubic eq 22 solves), ``slope`` its
    derivative in ``y``, ``d`` the coefficients' derivatives (implicit-function theorem)."""
    dq: float = d[0] - (d[0] + y * (d[1] + y * (d[2] + y * d[3]))) / slope
    return dq


@kernel
def _line_derivative(h0: float, h1: float, lin: float, b: _Blow, k_leak: float, dq: float,
                     d: _Blow, dh0_own: float, dh1_own: float) -> float:
    """Derivative of eq 29's ``H0 + H1 (Q − B0)`` in one parameter (``dq = Q − B0``,
    ``lin = H1/(K_leak/B1 + K_port)``), through ``B0`` and ``B1`` (``d``) and the
    parameter's own terms in ``H0`` and ``H1`` (``dh0_own``, ``dh1_own``)."""
    db0, db1 = d[0], d[1]
    dh0 = h0 * FLOW_EXPONENT * db0 / b[0] + dh0_own
    dh1 = h1 * 0.75 * db0 / b[0] - lin * k_leak * db1 / (b[1] * b[1]) + dh1_own
    return dh0 + dh1 * dq - h1 * db0


@kernel
def pressure_drop_gradient(q_tot: float, k_leak: float, k_port: float, k_spring: float,
                           preload_pa: float, g: float, nu_m2_s: float, form: int
                           ) -> tuple[float, float, float, float, float, float]:
    """``Δp(Q)`` [Pa] (:func:`pressure_drop`'s number, to its last bit) and its derivatives with
    respect to ``(K_leak, K_port, K_spring, Δp0, G)``, analytically: the chain rule through
    eq 28's smoothing of eq 15 (closed) and eqs 27/29 (open), the blow-off coefficients
    (eqs 23, 40–43) and the leak flow of the open valve by the implicit-function theorem
    on the equation it solves (the cubic of eq 22, or eq 19 for the exact form).  The same
    numbers as the complex-step derivative of :func:`pressure_drop` to 10⁻¹³ of each
    column's largest entry, except at large flows of eq 22's Cardano form, where the
    complex step loses digits to cancellation (3·10⁻¹⁰; a 50-digit evaluation agrees with
    this one to 2·10⁻¹³); in one evaluation instead of five complex ones.
    """
    nu4 = nu_m2_s ** 0.25
    closed = pressure_drop_closed(q_tot, k_leak, k_port, nu_m2_s)
    opened, q_leak, b0, b1, b2, b3 = _open_branch(q_tot, k_leak, k_port, k_spring,
                                                  preload_pa, nu_m2_s, form)
    dp = smooth_transition(opened, closed, g)
    if closed == 0.0 or opened == 0.0:
        return dp, 0.0, 0.0, 0.0, 0.0, 0.0
    b = (b0, b1, b2, b3)
    # per parameter K_leak, K_spring, Δp0: c = Δp0^1.5/K_spring, B0 ∝ (Δp0/K_leak)^(4/7)
    db_kl = _blow_off_derivative(b, 0.0, -1.0 / (FLOW_EXPONENT * k_leak))
    db_ks = _blow_off_derivative(b, -1.0 / k_spring, 0.0)
    db_p0 = _blow_off_derivative(b, 1.5 / preload_pa, 1.0 / (FLOW_EXPONENT * preload_pa))
    port = nu4 * q_tot ** FLOW_EXPONENT  # ∂/∂K_port of eq 15, and of eq 27 above B0
    if q_tot >= b0:
        leak = nu4 * k_leak * q_leak ** FLOW_EXPONENT  # eq 27's leak term
        e_leak = FLOW_EXPONENT * leak / q_leak          # its derivative in Q_leak
        if form == FORM_EXACT:
            # eq 19: Q_tot = Q_leak + (p − Δp0) √p / K_spring, p = K_leak ν^¼ Q_leak^(7/4)
            p = leak
            root_p = p ** 0.5
            d_term = (p + 0.5 * (p - preload_pa)) / (root_p * k_spring)  # d(last term)/dp
            slope = 1.0 + e_leak * d_term
            dql_kl = -(p / k_leak) * d_term / slope
            dql_ks = (p - preload_pa) * root_p / (k_spring * k_spring) / slope
            dql_p0 = root_p / k_spring / slope
        else:
            y = q_leak - b0
            slope = b1 + y * (2.0 * b2 + 3.0 * y * b3)
            dql_kl = _cubic_root_derivative(y, slope, db_kl)
            dql_ks = _cubic_root_derivative(y, slope, db_ks)
            dql_p0 = _cubic_root_derivative(y, slope, db_p0)
        do_kl = leak / k_leak + e_leak * dql_kl
        do_kp = port
        do_ks = e_leak * dql_ks
        do_p0 = e_leak * dql_p0
    else:
        h0, h1 = low_flow_line(b0, b1, k_leak, k_port, nu4)
        lin = FLOW_EXPONENT * nu4 * b0 ** 0.75  # H1 = lin (K_leak/B1 + K_port), eq 48
        own = h0 / (k_leak + k_port)           # ∂H0/∂K_leak = ∂H0/∂K_port at fixed B0
        dq = q_tot - b0
        do_kl = _line_derivative(h0, h1, lin, b, k_leak, dq, db_kl, own, lin / b1)
        do_kp = own + lin * dq
        do_ks = _line_derivative(h0, h1, lin, b, k_leak, dq, db_ks, 0.0, 0.0)
        do_p0 = _line_derivative(h0, h1, lin, b, k_leak, dq, db_p0, 0.0, 0.0)
    # eq 28: Δp = o c / (|o|^G + |c|^G)^(1/G)
    a_o, a_c = abs(opened), abs(closed)
    pow_o, pow_c = a_o ** g, a_c ** g
    total = pow_o + pow_c
    ds_do = dp / opened * (pow_c / total)
    ds_dc = dp / closed * (pow_o / total)
    ds_dg = dp * (math.log(total) / (g * g)
                  - (pow_o * math.log(a_o) + pow_c * math.log(a_c)) / (g * total))
    return (dp, ds_do * do_kl + ds_dc * port, ds_do * do_kp + ds_dc * port,
            ds_do * do_ks, ds_do * do_p0, ds_dg)


@batch_kernel
def _pressure_drop_loop(q: NDArray[np.float64], k_leak: float, k_port: float, k_spring: float,
                        preload_pa: float, g: float, nu_m2_s: float, form: int,
                        out: NDArray[np.float64]) -> None:
    """:func:`pressure_drop` at each flow, the valve's :func:`open_constants` once."""
    const = open_constants(k_leak, k_port, k_spring, preload_pa, nu_m2_s)
    for i in range(q.size):
        out[i] = pressure_drop_with(q[i], k_leak, k_port, k_spring, preload_pa, g, nu_m2_s,
                                    form, const)


def form_code(form: str) -> int:
    """Numeric code of a valve form name (``"cardano"`` or ``"exact"``)."""
    try:
        return VALVE_FORMS.index(form)
    except ValueError:
        raise UserError(f"valve form must be one of {VALVE_FORMS}, not {form!r}") from None


def pressure_drop_array(q_m3_s: ArrayLike, valve: Iterable[float], nu_m2_s: float,
                        form: str = "cardano") -> NDArray[np.float64]:
    """``Δp(Q)`` [Pa] of one valve over an array of flow magnitudes [m³/s].

    Parameters
    ----------
    q_m3_s : array_like
        Flow magnitudes, ``>= 0``.
    valve : ValveParams or tuple
        ``(k_leak, k_port, k_spring, preload_pa, smoothing_g)``.
    nu_m2_s : float
        Kinematic viscosity of the oil [m²/s].
    form : {"cardano", "exact"}
        Open-valve solution: eq 22 as published, or the exact root of eq 19.

    Returns
    -------
    ndarray
        Pressure drop magnitudes, same shape as ``q_m3_s``.
    """
    q = np.array(q_m3_s, dtype=float)  # a copy: contiguous, shape kept (also 0-d)
    out = np.empty(q.size)
    k_leak, k_port, k_spring, preload, g = tuple(valve)
    _pressure_drop_loop(q.ravel(), k_leak, k_port, k_spring, preload, g, nu_m2_s,
                        form_code(form), out)
    return out.reshape(q.shape)


#: Imaginary step of the complex-step derivative (relative to each parameter): small enough
#: that the result is exact to round-off, with no subtractive cancellation.
COMPLEX_STEP = 1e-30


@batch_kernel
def _pressure_drop_jacobian_loop(q: NDArray[np.float64], k_leak: float, k_port: float,
                                 k_spring: float, preload_pa: float, g: float, nu_m2_s: float,
                                 form: int, out: NDArray[np.float64]) -> None:
    for i in range(q.size):
        _, out[i, 0], out[i, 1], out[i, 2], out[i, 3], out[i, 4] = pressure_drop_gradient(
            q[i], k_leak, k_port, k_spring, preload_pa, g, nu_m2_s, form)


def pressure_drop_jacobian(q_m3_s: ArrayLike, valve: Iterable[float], nu_m2_s: float,
                           form: str = "cardano") -> NDArray[np.float64]:
    """Derivatives of ``Δp(Q)`` with respect to the valve parameters.

    Analytic (:func:`pressure_drop_gradient`): the complex-step derivative of
    :func:`pressure_drop` to 10⁻¹³ … 3·10⁻¹⁰ of each column's largest entry (tested), at a
    ninth of its cost (6,700 flows: 21.4 → 2.4 ms): the identification's
    valve fits had spent a sixth of a diagnosis in five complex evaluations per sample
    (benchmarks/diagnose_bench.py).

    Returns
    -------
    ndarray, shape (n, 5)
        ``∂Δp/∂(k_leak, k_port, k_spring, preload_pa, smoothing_g)`` [Pa per unit].
    """
    q = np.ascontiguousarray(q_m3_s, dtype=float).ravel()
    out = np.empty((q.size, 5))
    k_leak, k_port, k_spring, preload, g = (float(v) for v in valve)
    _pressure_drop_jacobian_loop(q, k_leak, k_port, k_spring, preload, g, nu_m2_s,
                                 form_code(form), out)
    return out


@batch_kernel
def _pressure_drop_slope_loop(q: NDArray[np.float64], k_leak: float, k_port: float,
                              k_spring: float, preload_pa: float, g: float, nu_m2_s: float,
                              form: int, out: NDArray[np.float64]) -> None:
    for i in range(q.size):
        h = COMPLEX_STEP * max(q[i], 1e-12)
        out[i] = pressure_drop(q[i] + 1j * h, k_leak + 0j, k_port + 0j, k_spring + 0j,
                               preload_pa + 0j, g + 0j, nu_m2_s, form).imag / h


def pressure_drop_slope(q_m3_s: ArrayLike, valve: Iterable[float], nu_m2_s: float,
                        form: str = "cardano") -> NDArray[np.float64]:
    """``dΔp/dQ`` [Pa s/m³] of one valve (complex step, exact to round-off)."""
    q = np.ascontiguousarray(q_m3_s, dtype=float).ravel()
    out = np.empty(q.size)
    k_leak, k_port, k_spring, preload, g = (float(v) for v in valve)
    _pressure_drop_slope_loop(q, k_leak, k_port, k_spring, preload, g, nu_m2_s,
                              form_code(form), out)
    return out
