"""Gas spring of the mono-tube damper (Simms & Crolla eq 3)."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.jit import kernel

#: a stroke: one value, or an array of them (the result has its type)
_X = TypeVar("_X", float, NDArray[np.float64])


def compression_chamber_pressure(x_m: _X, p_gas_static_pa: float, v_gas_static_m3: float,
                                 rod_area_m2: float, gamma: float) -> _X:
    """Compression-chamber (gas) pressure ``P_com`` [Pa], eq 3.

    ``P_com = P_gas,static (V_gas,static / (V_gas,static + A_rod x))^γ``: extension (``x > 0``)
    withdraws the rod and enlarges the gas volume.  Works on scalars and numpy arrays (the
    kernels call :data:`compression_chamber_pressure_kernel`, this source compiled).
    """
    p_com: _X = p_gas_static_pa * (v_gas_static_m3 / (v_gas_static_m3 + rod_area_m2 * x_m)) \
        ** gamma
    return p_com


#: :func:`compression_chamber_pressure` compiled for the kernels, on scalars (the kernels
#: run without numba's runtime and cannot allocate the array an array argument returns)
compression_chamber_pressure_kernel = kernel(compression_chamber_pressure)
