"""The adaptive damper's solenoid bypass (docs/model.md §6): the project's 'normal' and 'comfort'
settings of the paper's triple-rate damper.

The paper's damper is a triple-rate adaptive unit whose softer settings open an extra bypass
flow path with a solenoid; only 'sport' is parameterised (docs/model.md §2.3).  We model the
bypass as one short circular orifice **in parallel with the piston valve**, driven by the
same pressure difference ``Δp = p_reb − p_com`` as the valve flow ``Q_pv`` of eq 2, so the
flow the rebound chamber loses in eq 2 becomes ``Q_pv(Δp) + Q_b(Δp)``.

Pressure–flow law (laminar + turbulent losses of a short bore of length ``L`` and open area
``A``)::

    Δp = (a Q + b Q|Q|) / A²,      a = 8 π ρ ν L,      b = ρ / (2 C_d²)

``a Q / A²`` is Hagen–Poiseuille, ``128 μ L Q / (π d⁴)``, written through ``A = π d²/4``
(``μ = ρ ν``, ``ν`` the oil viscosity of the damper group); ``b Q|Q| / A²`` the orifice
loss with discharge coefficient ``C_d``.  Its inverse, the form the implicit step needs, is
taken in the rationalised form (no cancellation when the laminar term dominates)::

    Q_b(Δp) = sign(Δp) (−a + √(a² + 4 b A² |Δp|)) / (2b)
            = 2 A² Δp / (a + √(a² + 4 b A² |Δp|))
    dQ_b/dΔp = A² / √(a² + 4 b A² |Δp|)          (finite at Δp = 0: A²/a)

and ``Q_b ≡ 0`` when ``A = 0``.  Flow is positive from the rebound to the compression
chamber, like ``Q_pv`` (docs/model.md §1).

Valve command ``c ∈ [0, 1]``: 0 = 'comfort' (softest), 0.5 = 'normal', 1 = 'sport' (bypass
closed: the paper's damper).  The open area is piecewise linear in ``c`` through
``(0, A_comfort)``, ``(0.5, A_normal)``, ``(1, 0)``.  The solenoid follows the commanded
value as a first-order lag whose time constant is ``t63`` (63 % of a step after ``t63``),
integrated exactly over each step ``dt``::

    c_eff ← c_eff + (c_cmd − c_eff)(1 − exp(−dt / t63))

Parameters: the ``damper.adaptive`` group of ``config/sport.yaml``
(:class:`damper_emulator.params.AdaptiveParams`).  With the defaults there (ρ = 870 kg/m³,
C_d = 0.7, L = 3 mm, comfort 3.3 mm, normal 2.6 mm, t63 = 12 ms) the quasi-steady force at
the static position, less the static gas force ``F − F_static`` (friction included), is,
relative to 'sport' (measured, :func:`~damper_emulator.model.compressible.quasi_steady_force`):

=========  ===================  ===================  ====================
velocity   comfort (reb / com)  normal (reb / com)   sport F − F_static
=========  ===================  ===================  ====================
0.1 m/s    0.059 / 0.157        0.105 / 0.273        1899 / −709 N
0.3 m/s    0.212 / 0.550        0.428 / 0.739        2976 / −1014 N
0.5 m/s    **0.445** / 0.660    **0.708** / 0.771    3487 / −1299 N
1.0 m/s    0.712 / 0.692        0.819 / 0.791        4511 / −2077 N
=========  ===================  ===================  ====================

The diameters were chosen for the 0.5 m/s rebound figures (targets 40–50 % and 65–75 %).
Below the blow-off preload (eq 10; 2.74 MPa in rebound) the piston valve passes only its
leak flow (eq 15), so the bypass takes most of the flow and the soft settings are much
softer still at low speed; above it the opening blow-off valve takes over and the settings
converge.

The kernels here are pure numba (:func:`damper_emulator.model.jit.kernel`); the compressible
model (:mod:`damper_emulator.model.compressible`) calls them from its step.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.model.jit import kernel

#: Commands of the three settings named in the paper.
SETTINGS = {"comfort": 0.0, "normal": 0.5, "sport": 1.0}

#: The lag snaps the effective command onto the commanded one once they differ by less than
#: this (so that a settled 'sport' command is exactly 1 and the bypass exactly closed).
SNAP = 1e-12


def bypass_coefficients(oil_density_kg_m3: float, oil_kinematic_viscosity_m2_s: float,
                        bypass_length_m: float, discharge_coefficient: float
                        ) -> tuple[float, float]:
    """``(a, b)`` of ``Δp = (a Q + b Q|Q|)/A²``: ``a = 8 π ρ ν L`` [kg/(m s)] (laminar,
    Hagen–Poiseuille), ``b = ρ / (2 C_d²)`` [kg/m³] (turbulent orifice loss)."""
    a = 8.0 * math.pi * oil_density_kg_m3 * oil_kinematic_viscosity_m2_s * bypass_length_m
    b = oil_density_kg_m3 / (2.0 * discharge_coefficient ** 2)
    return a, b


def circle_area(diameter_m: float) -> float:
    """``π d² / 4`` [m²]."""
    return math.pi / 4.0 * diameter_m ** 2


@kernel
def bypass_flow(dp: float, area: float, a: float, b: float) -> tuple[float, float]:
    """Bypass flow ``Q_b`` [m³/s] (rebound → compression +) at ``Δp`` [Pa] through the open
    area ``area`` [m²], and ``dQ_b/dΔp``; ``(0, 0)`` when the bypass is closed.

    Selects, no branch, and every division guarded by a test the compiler can see (so
    that it raises nothing): the SIMD lanes of :mod:`damper_emulator.model.lanes` run
    this inside their vectorised loop."""
    a2 = area * area if area > 0.0 else 0.0
    root = math.sqrt(a * a + 4.0 * b * a2 * abs(dp))
    den = a + root
    q = 2.0 * a2 * dp / den if den > 0.0 else 0.0
    dq = a2 / root if root > 0.0 else 0.0
    return q, dq


@kernel
def bypass_area(command: float, area_comfort: float, area_normal: float) -> float:
    """Open area [m²] at the (effective) command ``c``: piecewise linear through
    ``(0, A_comfort)``, ``(0.5, A_normal)``, ``(1, 0)``; 0 for ``c >= 1``."""
    if command >= 1.0:
        return 0.0
    if command >= 0.5:
        return area_normal * (2.0 - 2.0 * command)
    if command <= 0.0:
        return area_comfort
    return area_comfort + 2.0 * command * (area_normal - area_comfort)


@kernel
def solenoid_lag(effective: float, commanded: float, dt: float, t63: float) -> float:
    """The effective command after ``dt`` [s] of the first-order lag with time constant
    ``t63`` [s] (``t63 <= 0``: no lag), exact for a command held over the step."""
    if effective == commanded:
        return effective
    if t63 > 0.0:
        effective += (commanded - effective) * (-math.expm1(-dt / t63))
        if abs(commanded - effective) > SNAP:
            return effective
    return commanded


def bypass_pressure_drop(flow_m3_s: ArrayLike, area_m2: float, a: float, b: float
                         ) -> NDArray[np.float64]:
    """Forward law ``Δp = (a Q + b Q|Q|)/A²`` [Pa] (numpy; for checks and plots)."""
    q: NDArray[np.float64] = np.asarray(flow_m3_s, dtype=float)
    return (a * q + b * q * np.abs(q)) / area_m2 ** 2
