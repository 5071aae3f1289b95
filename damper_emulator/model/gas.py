"""Gas spring of the mono-tube damper (Simms & Crolla eq 3)."""

from __future__ import annotations

from damper_emulator.model.jit import kernel


@kernel
def compression_chamber_pressure(x_m, p_gas_static_pa, v_gas_static_m3, rod_area_m2, gamma):
    """Compression-chamber (gas) pressure ``P_com`` [Pa], eq 3.

    ``P_com = P_gas,static (V_gas,static / (V_gas,static + A_rod x))^γ``: extension (``x > 0``)
    withdraws the rod and enlarges the gas volume.  Works on scalars and numpy arrays.
    """
    return p_gas_static_pa * (v_gas_static_m3 / (v_gas_static_m3 + rod_area_m2 * x_m)) ** gamma
