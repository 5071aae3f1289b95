"""Batch simulation of the compressible model: the compiled loops over a whole history.

:func:`simulate_commanded_samples` runs the one compiled step
(:func:`damper_emulator.model.step.step`) over every sample of a displacement history with
a valve command and a measured temperature per sample, :func:`simulate_samples` at valve
command 1 ('sport') throughout; both start in quasi-steady equilibrium at the first sample
(:func:`damper_emulator.model.step.init_state`).
:func:`damper_emulator.model.compressible.simulate` checks the samples, runs the first and
returns a :class:`SimulationResult`; the replay runs either.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from damper_emulator.model.jit import batch_kernel
from damper_emulator.model.layout import S_CMD, S_CMD_EFF, S_FORCE, S_P_COM, S_P_REB, S_TEMP_IN
from damper_emulator.model.step import init_state, step

#: The kernels' arrays: packed parameters, valve-table coefficients, state, samples.
_Vec = NDArray[np.float64]


@batch_kernel
def simulate_commanded_samples(prm: _Vec, coef_r: _Vec, coef_c: _Vec, state: _Vec, t: _Vec, x: _Vec,
                        v: _Vec, command: _Vec, temperature: _Vec, force: _Vec, p_reb: _Vec,
                        p_com: _Vec, command_eff: _Vec, flags: NDArray[np.int64]) -> None:
    """The batch loop: ``command[i]`` is the valve command from sample ``i`` on (it drives
    the solenoid lag over the step to sample ``i + 1``); the start is settled at
    ``command[0]``.  ``temperature[i]`` [°C] (NaN: none) is the measured temperature the
    step to sample ``i`` sees (the viscosity–temperature extension)."""
    for i in range(t.size):
        state[S_TEMP_IN] = temperature[i]
        if i == 0:
            state[S_CMD] = command[0]
            state[S_CMD_EFF] = command[0]
            init_state(prm, coef_r, coef_c, state, x[0], v[0])
            force[0] = state[S_FORCE]
            flags[0] = 0
        else:
            force[i], flags[i] = step(prm, coef_r, coef_c, state, x[i], v[i], t[i] - t[i - 1])
        p_reb[i] = state[S_P_REB]
        p_com[i] = state[S_P_COM]
        command_eff[i] = state[S_CMD_EFF]
        state[S_CMD] = command[i]


@batch_kernel
def simulate_samples(prm: _Vec, coef_r: _Vec, coef_c: _Vec, state: _Vec, t: _Vec, x: _Vec, v: _Vec,
              force: _Vec, p_reb: _Vec, p_com: _Vec, flags: NDArray[np.int64]) -> None:
    """The batch loop at valve command 1 ('sport', bypass closed) throughout, whatever
    ``state`` holds (the replay passes a zero state)."""
    state[S_CMD] = 1.0
    state[S_CMD_EFF] = 1.0
    state[S_TEMP_IN] = math.nan
    for i in range(t.size):
        if i == 0:
            init_state(prm, coef_r, coef_c, state, x[0], v[0])
            force[0] = state[S_FORCE]
            flags[0] = 0
        else:
            force[i], flags[i] = step(prm, coef_r, coef_c, state, x[i], v[i], t[i] - t[i - 1])
        p_reb[i] = state[S_P_REB]
        p_com[i] = state[S_P_COM]


@dataclass(frozen=True)
class SimulationResult:
    """Output of :func:`~damper_emulator.model.compressible.simulate`, one value per input
    sample."""

    time_s: np.ndarray
    stroke_m: np.ndarray
    velocity_m_s: np.ndarray
    force_n: np.ndarray
    rebound_pressure_pa: np.ndarray
    compression_pressure_pa: np.ndarray
    faults: np.ndarray
    #: effective valve command (after the solenoid lag) at each sample
    valve_command_eff: np.ndarray | None = None
