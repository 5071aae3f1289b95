"""The safety layer of a damper in the loop: what the host never lets the rig do.

:class:`SafetyLayer` sits between the host's loop and the bus; it needs neither:

* **limits** (:class:`~ride_sim.hybrid.params.SafetyParams`): every demand is clamped
  into ``±stroke_limit_m`` and moves at most ``velocity_limit_m_s`` per second
  (:meth:`SafetyLayer.clamp`), whatever the car or the compensator ask; a measured stroke,
  velocity or force beyond its limit stops the run;
* **watchdog**: the run stops, and ``Enable`` is cleared, before the last valid
  ``DYNO_FEEDBACK`` is ``watchdog_s`` old (at :data:`WATCHDOG_TRIP` of it);
  a frame with a CRC, counter or length error never reaches :meth:`SafetyLayer.feedback`
  and so does not count as valid;
* **the host's own stall**: the run stops when the host's loop wakes ``watchdog_s`` (at
  :data:`WATCHDOG_TRIP` of it) or more after it last ran (:meth:`SafetyLayer.host_wakes`):
  it sent no ``DYNO_COMMAND`` meanwhile, and a rig that holds without commands has
  stopped following, while the feedback that waited, stamped on arrival, looks fresh;
* **instability**: per window of ``window_s``, the tracking error's r.m.s. over the
  reference stroke's (the all-numerical run's over the trailing ``reference_window_s``, at
  least half its r.m.s. over the ride so far, plus ``error_floor_m``); when it has grown
  by ``growth_ratio`` or more in each of ``growth_windows`` consecutive windows and
  exceeds ``error_ratio``, the loop is going unstable and the run stops before it reaches
  a limit.  A stable loop that merely
  tracks badly keeps the ratio bounded (an uncompensated rig lags by ``τ``: its error is
  about ``τ`` times the stroke velocity); an unstable one grows it without bound as the
  rig pumps energy into the car and the specimen.

A stop is final: :attr:`SafetyLayer.reason` holds its one-line reason, :attr:`enable` is
False from then on and the demand holds where it was.
"""

from __future__ import annotations

import math
from collections import deque

from damper_emulator.errors import DamperHilError
from ride_sim.hybrid.params import SafetyParams

#: The watchdog trips at this fraction of ``watchdog_s``: the rest is the margin for a
#: late cycle (without feedback the host cycles every period, give or take its jitter).
WATCHDOG_TRIP = 0.8


class RunStopped(DamperHilError, RuntimeError):
    """The safety layer stopped a run on the rig (one line: why).  ``timing``: the
    watchdog or a stall of the host stopped it (:attr:`SafetyLayer.timing`), not a limit
    the specimen reached: the run may go again."""

    def __init__(self, reason: str, timing: bool = False) -> None:
        super().__init__(reason)
        self.timing = timing


class SafetyLayer:
    """Limits, watchdog and instability detector (see the module docstring).

    Parameters
    ----------
    params : SafetyParams
    dt_s : float
        The host's cycle [s].
    """

    def __init__(self, params: SafetyParams, dt_s: float) -> None:
        self.params = params
        self.dt_s = float(dt_s)
        self.reason: str | None = None
        self.stopped_at_s: float | None = None
        #: the stop came from time (the watchdog, a stall of the host), not the specimen:
        #: a characterisation may run again (:class:`RunStopped`)
        self.timing = False
        self.last_valid_s: float | None = None
        self.last_host_s: float | None = None
        self.clamped = 0
        self._strokes: deque[tuple[int, float]] = deque()
        self._frames = 0
        self._span = max(1, int(round(params.velocity_span_s / dt_s)))
        self.velocity_m_s = 0.0
        self._window = max(1, int(round(params.window_s / dt_s)))
        self._sum_e = self._sum_r = 0.0
        self._count = 0
        self._reference_sums: deque[float] = deque(
            maxlen=max(1, int(round(params.reference_window_s / params.window_s))))
        self._total_r = 0.0
        self._windows = 0
        self._last_ratio = math.nan
        self._growing = 0
        self.error_ratios: list[float] = []

    @property
    def enable(self) -> bool:
        """Whether the rig may follow the demand (False after any stop)."""
        return self.reason is None

    def stop(self, t_s: float, reason: str, timing: bool = False) -> None:
        """Stop the run now (the first reason is kept); ``timing``: the watchdog or a
        stall of the host stopped it, not the specimen (:attr:`timing`)."""
        if self.reason is None:
            self.reason = reason
            self.stopped_at_s = float(t_s)
            self.timing = bool(timing)

    def clamp(self, demand_m: float, previous_m: float) -> float:
        """``demand_m`` within the stroke limits, at most the velocity limit's step from
        ``previous_m``; a NaN demand (a bug upstream) holds ``previous_m``."""
        p = self.params
        value = demand_m if math.isfinite(demand_m) else previous_m
        step = p.velocity_limit_m_s * self.dt_s
        value = min(max(value, previous_m - step), previous_m + step)
        value = min(max(value, -p.stroke_limit_m), p.stroke_limit_m)
        if value != demand_m:
            self.clamped += 1
        return value

    def feedback(self, t_s: float, stroke_m: float, force_n: float,
                 cycle: int | None = None) -> None:
        """A valid ``DYNO_FEEDBACK`` received at ``t_s``: feed the watchdog, check the
        measured stroke, velocity and force.  The velocity is the stroke's change over at
        least ``velocity_span_s`` of the rig's cycles: ``cycle`` numbers the frame's cycle
        (a lost frame leaves a gap); without it, one frame per cycle ``dt_s``.  Not the
        arrival times: they jitter (a host that stalled reads several frames at once)."""
        p = self.params
        self.last_valid_s = float(t_s)
        strokes = self._strokes
        self._frames += 1
        strokes.append((self._frames if cycle is None else int(cycle), float(stroke_m)))
        while len(strokes) > 2 and strokes[-1][0] - strokes[1][0] >= self._span:
            strokes.popleft()
        (c0, x0), (c1, x1) = strokes[0], strokes[-1]
        if c1 - c0 >= self._span:
            self.velocity_m_s = (x1 - x0) / ((c1 - c0) * self.dt_s)
        if not (math.isfinite(stroke_m) and math.isfinite(force_n)):
            self.stop(t_s, "the dyno reported a non-finite stroke or force")
        elif abs(stroke_m) > p.stroke_limit_m:
            self.stop(t_s, f"measured stroke {stroke_m * 1e3:+.1f} mm beyond the limit "
                           f"±{p.stroke_limit_m * 1e3:g} mm")
        elif abs(self.velocity_m_s) > p.velocity_limit_m_s:
            self.stop(t_s, f"measured velocity {self.velocity_m_s:+.2f} m/s beyond the "
                           f"limit ±{p.velocity_limit_m_s:g} m/s")
        elif abs(force_n) > p.force_limit_n:
            self.stop(t_s, f"measured force {force_n:+.0f} N beyond the limit "
                           f"±{p.force_limit_n:g} N")

    def await_feedback(self) -> None:
        """Run the watchdog again only from the next valid feedback on (a host that
        re-arms after a stall: the rig's own watchdog cleared Enable, and the frames of
        before it are no measure of the link)."""
        self.last_valid_s = None

    def watchdog(self, t_s: float) -> None:
        """Stop when the last valid feedback is :data:`WATCHDOG_TRIP` of ``watchdog_s``
        old: the command that clears ``Enable`` goes out within ``watchdog_s`` even when
        the host's cycle comes late."""
        if self.last_valid_s is None:
            return
        age = t_s - self.last_valid_s
        if age >= WATCHDOG_TRIP * self.params.watchdog_s:
            self.stop(t_s, f"no valid DYNO_FEEDBACK for {age * 1e3:.0f} ms (watchdog "
                           f"{self.params.watchdog_s * 1e3:g} ms)", timing=True)

    def host_wakes(self, t_s: float) -> None:
        """The host's loop runs at ``t_s`` [s, its monotonic clock, not a frame's stamp]:
        stop when it last ran :data:`WATCHDOG_TRIP` of ``watchdog_s`` or more ago."""
        last, self.last_host_s = self.last_host_s, float(t_s)
        if last is None:
            return
        gap = t_s - last
        if gap >= WATCHDOG_TRIP * self.params.watchdog_s:
            self.stop(t_s, f"the host stalled: no DYNO_COMMAND for {gap * 1e3:.0f} ms "
                           f"(watchdog {self.params.watchdog_s * 1e3:g} ms)", timing=True)

    def tracking(self, t_s: float, error_m: float, reference_m: float) -> None:
        """One cycle of the ride: the tracking error (measured − target stroke) and the
        reference run's stroke at this sample."""
        self._sum_e += error_m * error_m
        self._sum_r += reference_m * reference_m
        self._count += 1
        if self._count < self._window:
            return
        p = self.params
        sums = self._reference_sums
        sums.append(self._sum_r)
        self._total_r += self._sum_r
        self._windows += 1
        # the trailing r.m.s., and no less than half the ride's so far: the road ramping
        # out to a standstill does not make the car's settling an instability
        reference = max(math.sqrt(sum(sums) / (len(sums) * self._count)),
                        0.5 * math.sqrt(self._total_r / (self._windows * self._count)))
        ratio = math.sqrt(self._sum_e / self._count) / (reference + p.error_floor_m)
        self._sum_e = self._sum_r = 0.0
        self._count = 0
        self.error_ratios.append(ratio)
        growing = math.isfinite(self._last_ratio) and ratio >= p.growth_ratio \
            * self._last_ratio
        self._growing = self._growing + 1 if growing else 0
        self._last_ratio = ratio
        if self._growing >= p.growth_windows and ratio > p.error_ratio:
            self.stop(t_s, f"the loop is going unstable: the tracking error grew "
                           f"{self._growing} windows in a row to {ratio:.2g} times the "
                           "reference stroke")
