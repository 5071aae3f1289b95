"""The emulator's per-sample logic, free of ROS: input checks, hold / extrapolation between
input samples, input timeout and fault output, around one
:class:`~damper_emulator.model.compressible.DamperStepper`.

The ROS node (:mod:`damper_emulator.ros.emulator`) calls :meth:`EmulatorCore.submit` from
its subscription and :meth:`EmulatorCore.tick` from its fixed-rate loop (``trigger:
timer``), or :meth:`EmulatorCore.evaluate` once per input sample (``trigger: input``, used
by the lockstep simulation); the offline replay (:mod:`damper_emulator.replay`) drives the
same methods from a recorded bag, so node and replay compute the same forces.

Threading: :meth:`submit` (one writer) and :meth:`tick` (another thread) share only the
latest accepted sample, published as one tuple (an atomic store in CPython).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeVar, overload

from damper_emulator.model.compressible import DamperModel, DamperStepper
from damper_emulator.realtime.settings import FAULT_MODES, INPUT_MODES, EmulatorParams

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np
    from numpy.typing import NDArray

#: one tick's value, or an array of them (numpy)
_Sample = TypeVar("_Sample", float, "NDArray[np.float64]")

#: Period of the scripted ticks of :meth:`EmulatorCore.warm_up` [s].
WARM_UP_PERIOD_S = 1e-3


def stroke_window(stroke_limits_m: tuple[float, float], tolerance_m: float
                  ) -> tuple[float, float]:
    """Accepted input strokes: the damper's travel widened by ``tolerance_m`` on each side."""
    lo, hi = stroke_limits_m
    return lo - tolerance_m, hi + tolerance_m


@overload
def input_ok(stroke_m: float, velocity_m_s: float, stroke_window_m: tuple[float, float],
             max_velocity_m_s: float) -> bool: ...


@overload
def input_ok(stroke_m: NDArray[np.float64], velocity_m_s: NDArray[np.float64],
             stroke_window_m: tuple[float, float], max_velocity_m_s: float
             ) -> NDArray[np.bool_]: ...


def input_ok(stroke_m: _Sample, velocity_m_s: _Sample, stroke_window_m: tuple[float, float],
             max_velocity_m_s: float) -> bool | NDArray[np.bool_]:
    """The emulator's input rule, for a sample or for arrays of them (numpy): the stroke
    inside ``stroke_window_m`` and ``|velocity| <= max_velocity_m_s``.  NaN and infinite
    values fail it (every comparison with NaN is false, infinity is outside any window)."""
    lo, hi = stroke_window_m
    return (lo <= stroke_m) & (stroke_m <= hi) & (abs(velocity_m_s) <= max_velocity_m_s)


def fault_output(mode: str, last_force_n: _Sample, last_velocity_m_s: _Sample,
                 static_force_n: float, passive_rate_ns_m: float) -> _Sample:
    """The output while the input is missing or stale (``fault_mode``), for one tick or
    arrays of them: ``hold`` the last force, ``zero``, or ``passive`` (static gas force +
    ``passive_rate_ns_m`` × the last velocity)."""
    if mode == "zero":
        return last_force_n * 0.0
    if mode == "passive":
        return static_force_n + passive_rate_ns_m * last_velocity_m_s
    return last_force_n


class Status(enum.IntFlag):
    """Emulator status bits (also sent in the CAN ``DAMPER_FORCE`` status)."""

    OK = 0
    NO_INPUT = 1        # no valid input sample yet
    TIMEOUT = 2         # latest valid input older than input_timeout_s: fault output
    REJECTED = 4        # the latest input sample was rejected (non-finite, out of range)
    MODEL = 8           # the model flagged this step (clamped stroke/velocity, solver, ...)
    #: the node left 'active' (deactivated or shut down): this last output is the fault
    #: mode's and none follows.  ROS only: DAMPER_FORCE's 8-bit Status keeps bits 1..8 of
    #: the emulator, and the bridge's own force timeout (32) follows on the bus.
    INACTIVE = 16

    @property
    def fault(self) -> bool:
        """True when the output is a fault output rather than the model's force."""
        return bool(self & FAULT_OUTPUT)


#: the status bits of an output that is not the model's force
FAULT_OUTPUT = Status.NO_INPUT | Status.TIMEOUT | Status.INACTIVE


@dataclass(frozen=True)
class Output:
    """One evaluation: the force and the input sample it used."""

    force_n: float          # rebound +
    stroke_m: float         # stroke used (after hold / extrapolation)
    velocity_m_s: float
    stamp_ns: int           # stamp of the input sample used (0: none)
    input_age_s: float      # age of that sample at evaluation (nan: none)
    status: Status
    model_fault: int        # Fault bits of the model step (0 when not stepped)


@dataclass
class Counters:
    """Input and fault counters since start."""

    accepted: int = 0
    rejected_non_finite: int = 0
    rejected_range: int = 0
    rejected_stamp: int = 0
    timeouts: int = 0           # transitions into TIMEOUT
    fault_ticks: int = 0        # outputs that were fault outputs
    model_faults: int = 0       # steps with model Fault bits
    last_rejection: str = ""

    @property
    def rejected(self) -> int:
        return self.rejected_non_finite + self.rejected_range + self.rejected_stamp

    def reject(self, kind: str, reason: str) -> str:
        """Count a rejected input of ``kind`` (``non_finite``, ``range``, ``stamp``);
        returns ``reason``."""
        setattr(self, f"rejected_{kind}", getattr(self, f"rejected_{kind}") + 1)
        self.last_rejection = reason
        return reason


class EmulatorCore:
    """Compressible damper model behind input checks and a timeout.

    Parameters
    ----------
    model : DamperModel
    params : EmulatorParams
    """

    def __init__(self, model: DamperModel, params: EmulatorParams):
        self.model = model
        self.params = params
        # the initial valve command, settled (docs/model.md §6; no effect without a bypass)
        self.stepper = DamperStepper(model, valve_command=params.valve_command)
        #: force at rest at the static position (eq 30's gas force), the passive baseline
        self.static_force_n = self.stepper.force_n
        self._stroke_range = model.stroke_limits_m
        self.counters = Counters()
        self.valve_command = params.valve_command
        self._latest: tuple[int, int, float, float] | None = None  # recv, stamp, x, v
        self._last_step_ns: int | None = None   # time base of the last model step
        self._last_force = self.static_force_n
        self._last_velocity = 0.0
        self._in_timeout = False
        self._rejected_flag = False

    def warm_up(self) -> None:
        """Exercise every path a running node can take (its compiled kernels loaded or
        compiled, each branch run once) on scratch copies, before the node says it is
        ready: the model step of both triggers and input modes, every fault output mode,
        a timeout, rejected input and a valve command.  This core's own state is not
        touched.  See :meth:`DamperStepper.warm_up`."""
        self.stepper.warm_up()
        p = self.params
        lo, hi = self._stroke_range
        period_ns = int(WARM_UP_PERIOD_S * 1e9)
        timeout_ns = int(p.input_timeout_s * 1e9) + period_ns
        for mode in INPUT_MODES:
            for fault in FAULT_MODES:
                scratch = EmulatorCore(self.model, dataclasses.replace(
                    p, input_mode=mode, fault_mode=fault))
                scratch.tick(0)                                   # no input yet
                for k in range(1, 4):
                    scratch.submit(k * period_ns, 0.001 * k, 0.1, k * period_ns)
                    scratch.tick(k * period_ns)
                scratch.set_valve_command(0.0)
                scratch.tick(4 * period_ns)
                scratch.tick(4 * period_ns + timeout_ns)          # input timeout
                scratch.submit(0, math.nan, 0.0, 0)               # rejected inputs
                scratch.submit(0, 2.0 * hi - lo, 0.0, 0)
                scratch.submit(0, 0.0, 2.0 * p.max_velocity_m_s, 0)
                scratch.set_valve_command(math.nan)
                scratch.tick(5 * period_ns + timeout_ns)
        scratch = EmulatorCore(self.model, p)                     # trigger: input
        for k in range(1, 4):
            scratch.evaluate(k * period_ns, 0.001 * k, 0.1)
        scratch.evaluate(period_ns, 0.0, 0.0)                     # stamp not after
        scratch.evaluate(5 * period_ns, math.nan, 0.0)

    # ---- input ------------------------------------------------------------------------

    @property
    def stroke_window_m(self) -> tuple[float, float]:
        """Accepted input strokes: the travel widened by ``stroke_tolerance_m``."""
        return stroke_window(self._stroke_range, self.params.stroke_tolerance_m)

    def check_input(self, stroke_m: float, velocity_m_s: float) -> str | None:
        """Why this sample is rejected (:func:`input_ok`), or None.  Counts the rejection."""
        vmax = self.params.max_velocity_m_s
        if input_ok(stroke_m, velocity_m_s, self.stroke_window_m, vmax):
            return None
        c = self.counters
        if not (math.isfinite(stroke_m) and math.isfinite(velocity_m_s)):
            return c.reject("non_finite", f"non-finite input (stroke {stroke_m}, velocity "
                                          f"{velocity_m_s})")
        if abs(velocity_m_s) <= vmax:
            lo, hi = self._stroke_range
            return c.reject("range", f"stroke {stroke_m:.4g} m outside the travel "
                                     f"[{lo:.4g}, {hi:.4g}] m")
        return c.reject("range", f"|velocity| {abs(velocity_m_s):.4g} m/s above {vmax:g} m/s")

    def reject_malformed(self, reason: str) -> str:
        """Count an input message that holds no usable sample (e.g. a JointState without
        position or velocity) and flag the next output :attr:`Status.REJECTED`, as
        :meth:`submit` does for a sample it rejects; returns ``reason``."""
        self._rejected_flag = True
        return self.counters.reject("range", reason)

    def submit(self, stamp_ns: int, stroke_m: float, velocity_m_s: float,
               now_ns: int) -> str | None:
        """Offer an input sample received at ``now_ns`` (``trigger: timer``).

        Returns the rejection reason, or None when the sample was accepted (it becomes the
        sample the next :meth:`tick` uses).
        """
        reason = self.check_input(stroke_m, velocity_m_s)
        self._rejected_flag = reason is not None
        if reason is None:
            self.counters.accepted += 1
            self._latest = (int(now_ns), int(stamp_ns), float(stroke_m), float(velocity_m_s))
        return reason

    def set_valve_command(self, value: float) -> str | None:
        """Accept a valve command in [0, 1] (0 comfort .. 1 sport) and pass it to the
        model, whose solenoid lag it drives from the next step on; returns the rejection
        reason or None."""
        if not (math.isfinite(value) and 0.0 <= value <= 1.0):
            return f"valve command {value} outside [0, 1]"
        self.valve_command = float(value)
        self.stepper.set_valve_command(self.valve_command)
        return None

    # ---- output -----------------------------------------------------------------------

    def fault_force(self) -> float:
        """The output while the input is missing or stale (:func:`fault_output`)."""
        p = self.params
        return fault_output(p.fault_mode, self._last_force, self._last_velocity,
                            self.static_force_n, p.passive_rate_ns_m)

    def tick(self, now_ns: int) -> Output:
        """Evaluate at ``now_ns`` from the latest accepted sample (``trigger: timer``)."""
        sample = self._latest
        flag = Status.REJECTED if self._rejected_flag else Status.OK
        if sample is None:
            self.counters.fault_ticks += 1
            return Output(self.fault_force(), math.nan, math.nan, 0, math.nan,
                          Status.NO_INPUT | flag, 0)
        recv_ns, stamp_ns, x, v = sample
        age_s = (now_ns - recv_ns) * 1e-9
        if age_s > self.params.input_timeout_s:
            if not self._in_timeout:
                self.counters.timeouts += 1
                self._in_timeout = True
            self.counters.fault_ticks += 1
            return Output(self.fault_force(), x, v, stamp_ns, age_s,
                          Status.TIMEOUT | flag, 0)
        self._in_timeout = False
        if self.params.input_mode == "extrapolate":
            x = x + v * min(max(age_s, 0.0), self.params.max_extrapolation_s)
        return self._step(now_ns, x, v, stamp_ns, age_s, flag)

    def evaluate(self, stamp_ns: int, stroke_m: float, velocity_m_s: float) -> Output | None:
        """One force for one input sample (``trigger: input``): the model is advanced by the
        difference of the samples' stamps.  Returns None for a rejected sample (counted;
        the reason is in ``counters.last_rejection``)."""
        if self.check_input(stroke_m, velocity_m_s) is not None:
            return None
        if self._last_step_ns is not None and stamp_ns <= self._last_step_ns:
            self.counters.reject("stamp", f"input stamp {stamp_ns} ns not after the previous "
                                          f"one {self._last_step_ns} ns")
            return None
        self.counters.accepted += 1
        return self._step(int(stamp_ns), float(stroke_m), float(velocity_m_s), int(stamp_ns),
                          0.0, Status.OK)

    def _step(self, time_ns: int, x: float, v: float, stamp_ns: int, age_s: float,
              flag: Status) -> Output:
        if self._last_step_ns is None:
            self.stepper.reset(x, v)
            force, fault = self.stepper.force_n, 0
        else:
            force, fault = self.stepper.step(x, v, (time_ns - self._last_step_ns) * 1e-9)
        self._last_step_ns = time_ns
        status = flag
        if fault:
            status |= Status.MODEL
            self.counters.model_faults += 1
        self._last_force = force
        self._last_velocity = v
        return Output(force, x, v, stamp_ns, age_s, status, int(fault))
