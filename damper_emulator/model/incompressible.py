"""Incompressible damper force (Simms & Crolla eqs 30–32), used for identification.

The compression chamber is held at the static gas pressure and the oil is rigid, so the
valve flow is ``Q = |ẋ| (A_pt − A_rod)`` (eqs 5–7) and the pressure drop follows the valve
characteristic of :mod:`damper_emulator.model.valve` directly.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.model.valve import pressure_drop_array

if TYPE_CHECKING:  # pragma: no cover
    from damper_emulator.params import ModelConfig


def valve_pressure_drop(velocity_m_s: ArrayLike, cfg: ModelConfig) -> NDArray[np.float64]:
    """Signed valve pressure drop ``p_reb − p_com`` [Pa] of a rigid-oil damper moving at
    ``velocity_m_s``: the rebound valve's ``Δp`` for ``ẋ > 0``, minus the compression
    valve's for ``ẋ < 0`` (eqs 5–29)."""
    d, form = cfg.damper, cfg.numerics.valve_form
    v = np.asarray(velocity_m_s, dtype=float)
    q = np.abs(v) * d.annulus_area_m2
    nu = d.oil_kinematic_viscosity_m2_s
    return np.where(v > 0, pressure_drop_array(q, d.rebound, nu, form),
                    -pressure_drop_array(q, d.compression, nu, form))


def incompressible_force(velocity_m_s: ArrayLike, cfg: ModelConfig) -> NDArray[np.float64]:
    """Damper force [N, rebound +] of the incompressible model, eqs 30–32.

    ``F = F_static + Δp (A_pt − A_rod) + F_friction sgn ẋ`` with ``F_static = −A_rod
    P_gas,static`` and ``Δp`` signed by :func:`valve_pressure_drop`.
    """
    d = cfg.damper
    v: NDArray[np.float64] = np.asarray(velocity_m_s, dtype=float)
    return (d.static_force_n + valve_pressure_drop(v, cfg) * d.annulus_area_m2
            + d.friction_force_n * np.sign(v))
