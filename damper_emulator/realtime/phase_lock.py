"""Phase lock of a fixed-rate loop to the arrivals of its input.

A timer-triggered emulator computes its force at its own ticks from the latest input.  The
time an input waits for the next tick adds to the state→force latency: anywhere from 0 to a
whole period, set by where the sender's and the loop's phases happened to start.  A dyno
that sends a stroke every cycle and reads the force on its next one sees that wait in
full.  The lock moves the loop's ticks, a little at a time, to follow each input's arrival
by a set lag, as a fieldbus slave follows its master's cycle: the rate stays the loop's
(or, if the input's clock runs slightly faster or slower, follows it: up to about 1 %,
the lag then off the target by the closed form below), only the phase moves.

The lock is a first-order loop on the phase error ``e = wrap(lag − target)`` (``lag``: from
the input's arrival to the tick that took it; ``wrap`` into ``[−P/2, P/2)`` of the period
``P``, so that an input that arrived just after a tick moves the ticks later, not a whole
period earlier): each tick that took exactly one new input shifts the next deadline by
``−gain·e``, at most :data:`MAX_STEP_FRACTION` of a period.  A constant error decays as
``(1 − gain)^n`` over ``n`` such ticks; an input period ``P_in`` off the loop's leaves a
standing error ``(P − P_in)/gain`` (1 % of a 1 ms period: 0.1 ms), so that beyond about
1 % the lag leaves the period and inputs slip a tick.  Only a tick that took one input
after a tick that took one input corrects: the input then comes at the loop's rate.  Ticks
that took none or several, and a single input between such ticks (an input at another
rate, 1.5 or 0.3 times the loop's, or a burst), carry no phase and leave the ticks where
they are.
"""

from __future__ import annotations

#: fraction of the phase error corrected per tick that took one input: the arrival's
#: jitter (tens of µs) is averaged over about 1/gain ticks
GAIN = 0.1
#: the most a deadline moves per tick, as a fraction of the period (the loop's period
#: error stays within it; an input clock within ±2 % of the loop's is followed)
MAX_STEP_FRACTION = 0.02


def wrap(error_ns: int, period_ns: int) -> int:
    """``error_ns`` wrapped into ``[−period/2, period/2)``."""
    half = period_ns // 2
    return (error_ns + half) % period_ns - half


class PhaseLock:
    """The deadline shift that brings a loop's ticks to ``target_lag_ns`` after its input's
    arrival (module docstring).

    Parameters
    ----------
    period_ns : int
        The loop's nominal period [ns].
    target_lag_ns : int
        Wanted time from an input's arrival to the tick that takes it [ns], in
        ``(0, period_ns)``: longer than the arrival's jitter, or an input that arrives late
        waits a whole period.
    gain, max_step_fraction : float
        :data:`GAIN` and :data:`MAX_STEP_FRACTION`.
    """

    def __init__(self, period_ns: int, target_lag_ns: int, gain: float = GAIN,
                 max_step_fraction: float = MAX_STEP_FRACTION):
        if not 0 < target_lag_ns < period_ns:
            raise ValueError(f"target lag {target_lag_ns} ns outside (0, {period_ns}) ns")
        self.period_ns = int(period_ns)
        self.target_lag_ns = int(target_lag_ns)
        self.gain = gain
        self.max_step_ns = int(max_step_fraction * period_ns)
        #: phase error of the latest tick that corrected [ns] (0 before any)
        self.error_ns = 0
        self._previous_inputs = 0

    def shift_ns(self, inputs: int, lag_ns: int) -> int:
        """The shift of the next deadline [ns] after a tick that took ``inputs`` new inputs,
        the newest of them ``lag_ns`` after its arrival (+: later); call it every tick."""
        previous, self._previous_inputs = self._previous_inputs, inputs
        if inputs != 1 or previous != 1:
            return 0
        self.error_ns = wrap(lag_ns - self.target_lag_ns, self.period_ns)
        step = int(round(-self.gain * self.error_ns))
        return max(-self.max_step_ns, min(self.max_step_ns, step))
