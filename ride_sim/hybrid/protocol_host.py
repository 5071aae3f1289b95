"""A dyno protocol on a physical damper over CAN: the host drives a known stroke history.

:class:`ProtocolHost` is the :class:`~ride_sim.hybrid.rig_host.RigHost` whose run proper
(phase ``test``) is a stroke history known in advance: a test protocol of
:mod:`damper_emulator.dyno.protocols` (quasi-static, chirp, sines) sampled at the rig's
cycle.  After the transfer system's identification the demand moves to the history's first
stroke (``approach``) and holds there a moment; then each cycle records the measured stroke
and force and demands the servo's inverse of the history a delay ahead, which is known
exactly (no prediction)::

    u = ( x + (2ζ/ω) v + a/ω² ) / g    at    t_k + d + T/2

with the delay and gain as the tracker follows them.  The instability detector compares the
tracking error with the history itself.  The measured data (stroke, force, the dyno's
temperature) are what ``damper-hil dyno`` writes.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from damper_emulator.realtime.worker import Executor
from ride_sim.hybrid.params import CompensatorParams, HybridRunParams, SafetyParams
from ride_sim.hybrid.rig_host import HOST_CYCLE_S, RigHost

#: The hold at the history's first stroke before it starts [s].
START_HOLD_S = 0.2


class ProtocolHost(RigHost):
    """Drives the stroke history ``stroke_m`` (one value per rig cycle ``dt_s``).

    Parameters
    ----------
    run : HybridRunParams
        Settle, approach, connect and identification-fit settings (the road's are unused).
    compensator, safety :
        As for :class:`~ride_sim.hybrid.host.HybridHost`.
    stroke_m : array_like
        The history [m, extension +], from the static position.
    dt_s : float
        The rig's cycle [s].
    """

    RUN_PHASE = "test"
    OWN_PHASES = ("approach",)

    def __init__(self, run: HybridRunParams, compensator: CompensatorParams,
                 safety: SafetyParams, stroke_m: Any, dt_s: float = HOST_CYCLE_S,
                 executor: Executor | None = None) -> None:
        x = np.ascontiguousarray(stroke_m, dtype=float)
        if x.ndim != 1 or x.size < 3 or not np.isfinite(x).all():
            raise ValueError("the stroke history must be a finite 1-D array of 3 samples or "
                             "more")
        super().__init__(run, compensator, safety, dt_s, x.size, executor)
        self.stroke = x
        self.velocity = np.gradient(x, self.dt_s)
        self.acceleration = np.gradient(self.velocity, self.dt_s)
        self._grid = np.arange(x.size, dtype=float)

    def _after_fit(self, t_s: float) -> tuple[float, float]:
        self._enter("approach", t_s)
        return self._approach(t_s, None, 0)

    def _approach(self, t_s: float, feedback: Any, t_ns: int) -> tuple[float, float]:
        start = float(self.stroke[0])
        if self._demand != start:
            self._phase_start_s = t_s                   # the hold starts at the position
            return self._toward(start), 0.0
        if self._elapsed(t_s) >= START_HOLD_S:
            self._enter(self.RUN_PHASE, t_s)
            self.k = 0
            return self._demand_after(-1)
        return start, 0.0

    def _demand_after(self, k: int) -> tuple[float, float]:
        """The demand sent once sample ``k`` is recorded: the servo's inverse of the
        history at ``k + d/T + 1/2``, clamped to its ends."""
        tracker, est = self.tracker, self.transfer
        assert tracker is not None and est is not None
        j = min(max(k + tracker.delay_s / self.dt_s + 0.5, 0.0), self.stroke.size - 1.0)
        x, v, a = (float(np.interp(j, self._grid, h))
                   for h in (self.stroke, self.velocity, self.acceleration))
        w = 2.0 * math.pi * est.bandwidth_hz
        lead = 2.0 * est.damping / w
        return (x + lead * v + a / (w * w)) / tracker.gain, (v + lead * a) / tracker.gain

    def _run_cycle(self, t_s: float, t_ns: int) -> tuple[float, float]:
        k = self.k
        if k >= self.stroke.size:
            self._enter("return", t_s)
            return self._return(t_s, None, t_ns)
        target = float(self.stroke[k])
        self._record_sample(k, target, t_ns)
        self.safety.tracking(t_s, self._measured - target, target)
        self.k = k + 1
        if not self.safety.enable:
            return self._demand, 0.0
        return self._demand_after(k)
