"""The virtual dyno's physics, one control cycle at a time (no bus here).

:class:`VirtualRig` is what ``damper-hil virtual-rig`` runs behind its CAN shell
(:mod:`can_bridge.virtual_rig`), and what the offline loop (:mod:`ride_sim.hybrid.offline`)
couples to the host directly:

* a valid ``DYNO_COMMAND`` goes to :meth:`VirtualRig.command` with its arrival time (its
  ``VelocityDemand`` moves the demand on between commands, as a dyno controller
  interpolates its set point);
* every cycle :meth:`VirtualRig.step` moves the actuator (:mod:`ride_sim.hybrid.actuator`:
  the demand in effect a transport delay after it arrived, through the servo), steps the
  specimen damper (the compressible model with any extension,
  :class:`~damper_emulator.model.compressible.DamperStepper`) at the achieved stroke and
  velocity, and returns what the rig's sensors read, noise included: the
  ``DYNO_FEEDBACK`` of the cycle.

The rig follows the demand while the latest command had ``Enable`` set and arrived within
``hold_after_s``; otherwise it holds where it is (``Status.enabled`` clear).  Its actuator
stops at ``travel_m``: a demand beyond is clamped there (``Status.at_limit``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from damper_emulator.model.compressible import DamperModel, DamperStepper
from ride_sim.hybrid.actuator import DelayLine, Servo
from ride_sim.hybrid.params import ActuatorParams, RigParams

#: ``DYNO_FEEDBACK.Status`` bits (as :class:`can_bridge.dbc.DynoStatus`, which the CAN
#: shell maps them to)
STATUS_ENABLED, STATUS_AT_LIMIT, STATUS_FAULT = 1, 2, 4

#: A demand moves on at its rate for at most this many cycles after it became due.
RATE_HOLD_CYCLES = 2

#: The oil temperature reported by a specimen without a thermal model [°C].
AMBIENT_TEMPERATURE_C = 25.0


@dataclass(frozen=True)
class Feedback:
    """What the rig measures in one cycle (the payload of ``DYNO_FEEDBACK``)."""

    stroke_m: float        # displacement sensor, extension +
    force_n: float         # load cell, rebound +
    status: int            # STATUS_* bits
    temperature_c: float   # the specimen's oil (DYNO_AUX)


class VirtualRig:
    """Actuator, specimen and sensors of a damper dyno.

    Parameters
    ----------
    model : DamperModel
        The specimen: the compressible model, with its extensions (e.g. a thermal fade).
    actuator : ActuatorParams
        Transport delay, servo dynamics and gain.
    rig : RigParams
        Rate, sensor noise, travel, command timeout, seed.
    """

    def __init__(self, model: DamperModel, actuator: ActuatorParams, rig: RigParams) -> None:
        self.actuator = actuator
        self.rig = rig
        self.period_s = 1.0 / rig.rate_hz
        self.servo = Servo(actuator)
        self.delay = DelayLine(actuator.delay_s, horizon_s=self._horizon())
        self.specimen = DamperStepper(model)
        thermal = model.cfg.damper.extensions.viscosity_temperature \
            if model.cfg.damper.extensions is not None else None
        self._base_temperature_c = (thermal.reference_temperature_c if thermal is not None
                                    else AMBIENT_TEMPERATURE_C)
        self._rng = np.random.default_rng(rig.seed)
        self._enable = False
        self._last_command_s = -math.inf
        self.following = False
        self.force_n = self.specimen.force_n

    def _horizon(self) -> float:
        """How long a demand moves on at its rate: :data:`RATE_HOLD_CYCLES` cycles (an
        interpolation to the next command, not an extrapolation through a stall: a chirp's
        1 m/s for the hold's 50 ms would be 50 mm)."""
        return RATE_HOLD_CYCLES * self.period_s

    def set_delay(self, delay_s: float) -> None:
        """Change the transport delay from now on (e.g. a slower bus mid-run)."""
        self.delay.delay_s = float(delay_s)

    def command(self, t_s: float, stroke_m: float, enable: bool,
                velocity_m_s: float = 0.0) -> None:
        """A valid ``DYNO_COMMAND`` arrived at ``t_s`` [s, the rig's clock]: the demand
        follows ``stroke_m`` and moves on at ``velocity_m_s`` until the next one is due
        (for at most :data:`RATE_HOLD_CYCLES` cycles)."""
        self._last_command_s = float(t_s)
        self._enable = bool(enable)
        if enable:
            self.delay.push(t_s, stroke_m, velocity_m_s)

    def step(self, t_s: float) -> Feedback:
        """The control cycle at ``t_s`` [s]: measure the specimen at the actuator's
        stroke now, then move the actuator towards the demand in effect now (held over the
        cycle).  Returns this cycle's measurement."""
        rig = self.rig
        x, v = self.servo.stroke_m, self.servo.velocity_m_s
        force, fault = self.specimen.step(x, v, self.period_s)
        self.force_n = float(force)
        follow = self._enable and (t_s - self._last_command_s) <= rig.hold_after_s
        if not follow and self.following:        # hold from here; forget pending demands
            self.delay = DelayLine(self.delay.delay_s, x, self._horizon())
        self.following = follow
        demand = self.delay.at(t_s) if follow else self.delay.at(-math.inf)
        status = STATUS_ENABLED if follow else 0
        if abs(demand) > rig.travel_m:
            demand = math.copysign(rig.travel_m, demand)
            status |= STATUS_AT_LIMIT
        x_next, _ = self.servo.step(demand, self.period_s)
        if abs(x_next) > rig.travel_m:            # the end stop
            self.servo.hold(math.copysign(rig.travel_m, x_next))
            status |= STATUS_AT_LIMIT
        if fault:
            status |= STATUS_FAULT
        noise = self._rng.standard_normal(2)
        return Feedback(x + rig.stroke_noise_m * float(noise[0]),
                        self.force_n + rig.force_noise_n * float(noise[1]), status,
                        self._base_temperature_c + self.specimen.temperature_rise_k)
