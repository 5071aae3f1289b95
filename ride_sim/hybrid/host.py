"""The host's side of a damper in the loop, one cycle at a time, free of any bus.

:class:`HybridHost` is called once per rig cycle with the newest valid ``DYNO_FEEDBACK``
(or ``None`` when none came) and returns the ``DYNO_COMMAND`` to send.  A run goes through
these phases:

``connect``
    ``Enable`` clear until the dyno's first feedback (none within ``connect_timeout_s``:
    the run fails, :attr:`HybridHost.failure`).
``settle``
    Enabled, the demand moves from where the rig stands to the static position at
    ``approach_speed_m_s`` and holds there ``settle_s``; the force's mean over the hold's
    second half is the static force the quarter car carries (the tare).
``identify``, ``fit``
    The low-amplitude test signal (:func:`~ride_sim.hybrid.transfer.excitation`), then
    the fit of the transfer system (:func:`~ride_sim.hybrid.transfer.identify`; run by the
    ``executor`` given, the demand held at the static position meanwhile).
``ride``
    Each cycle the quarter car (:class:`~ride_sim.session.RideSession`) takes the
    measured force for the current sample and advances; the compensator
    (:mod:`ride_sim.hybrid.compensator`) turns the car's next states into the demand; the
    tracker follows the rig's delay and gain; the twin (the damper's model on the
    measured motion) gives the force the model expects.  The road ramps in over
    ``ramp_s``, the evaluated ``duration_s`` follows, then the road ramps out.
``return``, ``done``
    The demand returns to the static position; ``Enable`` is cleared.
``stopped``
    The safety layer stopped the run (:mod:`ride_sim.hybrid.safety`): ``Enable`` clear,
    the demand held; :attr:`HybridHost.reason` says why.

Every demand passes :meth:`~ride_sim.hybrid.safety.SafetyLayer.clamp`, in every phase.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from damper_emulator.dyno.measured import write_measured_csv
from damper_emulator.model.compressible import DamperModel, DamperStepper
from ride_sim.dampers import CompressiblePlugin
from ride_sim.hybrid.compensator import Compensator
from ride_sim.hybrid.params import CompensatorParams, HybridRunParams, SafetyParams
from ride_sim.hybrid.rig import Feedback
from ride_sim.hybrid.safety import SafetyLayer
from ride_sim.hybrid.transfer import TransferEstimate, TransferTracker, excitation, identify
from ride_sim.params import QuarterCarParams, RoadParams
from ride_sim.quarter_car import RideResult, simulate
from ride_sim.road import iso8608_class
from ride_sim.session import RideSession
from ride_sim.study import metrics, random_road_input, start_state

#: The ride metrics ``hybrid.json`` reports (``ride`` and ``reference``).
RIDE_KEYS = ("sws_rms", "accel_w_rms", "dtl_rms")

#: Rows of the ride record (:attr:`HybridHost.record`), in ``hybrid.csv``'s order after
#: ``t_monotonic_ns`` and ``time``.
RECORD_COLUMNS = ("stroke_target", "stroke_command", "stroke_measured", "force_measured",
                  "force_model", "enable")


class Command(NamedTuple):
    """One ``DYNO_COMMAND``."""

    stroke_m: float
    velocity_m_s: float
    enable: bool


@dataclass(frozen=True)
class HybridRoad:
    """The ride's road: one height per cycle; ``[n_lead, n_lead + n_eval)`` is evaluated."""

    heights: np.ndarray
    n_lead: int
    n_eval: int

    @property
    def evaluated(self) -> slice:
        return slice(self.n_lead, self.n_lead + self.n_eval)


def hybrid_road(run: HybridRunParams, dt_s: float) -> HybridRoad:
    """The ISO 8608 random road of the run (eq 39 with the class's mean roughness),
    ramped in over ``ramp_s`` (raised cosine, taken from the periodic road's end), ramped
    out over ``ramp_s`` after the evaluated part and followed by ``ramp_s`` of flat road
    (the car settles).  Its longest wavelength is the shorter of 100 m and the evaluated
    length."""
    roughness = iso8608_class(run.road_class)
    length = run.speed_m_s * run.duration_s
    defaults = RoadParams()
    band = (max(defaults.band_cycles_per_m[0], 1.0 / length), defaults.band_cycles_per_m[1])
    road = dataclasses.replace(defaults, roughness=roughness.roughness,
                               waviness=roughness.waviness, length_m=length,
                               lead_in_s=run.ramp_s)
    heights, n_lead, n_eval = random_road_input(road, run.speed_m_s, run.seed, dt_s, band)
    n_ramp = n_lead
    ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(n_ramp) / max(n_ramp, 1))
    out = heights[n_lead: n_lead + n_ramp].copy() * ramp[::-1]
    heights = heights.copy()
    heights[:n_lead] *= ramp
    full = np.concatenate([heights, out, np.zeros(n_ramp)])
    return HybridRoad(full, n_lead, n_eval)


def reference_run(car: QuarterCarParams, model: DamperModel, road: HybridRoad, dt_s: float
                  ) -> tuple[RideResult, dict[str, float]]:
    """The all-numerical reference: the same road with the twin model in the loop."""
    damper = CompressiblePlugin(model, name="reference")
    result = simulate(car, damper, road.heights, dt_s,
                      initial_state=start_state(road.heights, dt_s))
    sl = road.evaluated
    return result, metrics(result, sl.start, sl.stop)


#: Phases of a run, in order (``stopped`` may follow any).
PHASES = ("connect", "settle", "identify", "fit", "ride", "return", "done", "stopped")


class _Immediate:
    """An executor that runs the work at once (offline runs, tests)."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        future: Future[Any] = Future()
        try:
            future.set_result(fn(*args))
        except Exception as exc:   # handed to the caller through the future
            future.set_exception(exc)
        return future


class HybridHost:
    """The host's loop (see the module docstring).

    Parameters
    ----------
    run : HybridRunParams
    car : QuarterCarParams
    twin : DamperModel
        The damper's model: the twin, the compensator's prediction and the reference.
    compensator : CompensatorParams
    safety : SafetyParams
    dt_s : float
        The rig's cycle [s] (the host runs once per feedback).
    executor : object with ``submit(fn, *args) -> Future``, optional
        Runs the identification's fit off the loop (default: at once, in the cycle).
    """

    def __init__(self, run: HybridRunParams, car: QuarterCarParams, twin: DamperModel,
                 compensator: CompensatorParams, safety: SafetyParams, dt_s: float = 1e-3,
                 executor: Any = None) -> None:
        self.run = run
        self.car = car
        self.twin_model = twin
        self.compensator_params = compensator
        self.dt_s = float(dt_s)
        self.safety = SafetyLayer(safety, dt_s)
        self.executor = executor if executor is not None else _Immediate()
        self.road = hybrid_road(run, dt_s)
        self.reference, self.reference_metrics = reference_run(car, twin, self.road, dt_s)
        self.phase = "connect"
        self.failure: str | None = None
        self._phase_start_s: float | None = None
        self._start_s: float | None = None
        self._demand = 0.0
        self._measured = math.nan
        self._force = math.nan
        self._tare: list[float] = []
        self.static_force_n = math.nan
        self._excitation = excitation(compensator.identify_s, dt_s,
                                      compensator.identify_amplitude_m,
                                      compensator.identify_band_hz, seed=run.seed)
        self.identification = np.full((2, self._excitation.size), np.nan)
        self._j = 0
        self._fit_job: Future[TransferEstimate] | None = None
        self.transfer: TransferEstimate | None = None
        self.tracker: TransferTracker | None = None
        self.session: RideSession | None = None
        self.comp: Compensator | None = None
        self.twin = DamperStepper(twin)
        n = self.road.heights.size
        self.record = np.full((len(RECORD_COLUMNS), n), np.nan)
        self.t_ns = np.zeros(n, dtype=np.int64)
        self.delay_estimate_s = np.full(n, np.nan)
        #: the dyno's latest oil temperature (DYNO_AUX) at each ride sample [°C]
        self.temperature_c = np.full(n, np.nan)
        self._temperature = math.nan
        self._prev_measured = (math.nan, math.nan)
        self._pending: tuple[float, float] | None = None
        self.k = 0

    def warm_up(self) -> None:
        """Load or compile what the loop runs (the damper's and the car's kernels, the
        compensator's prediction, the identification's fit) before its clock starts: a
        compile inside the loop would stall it past the watchdog."""
        stepper = DamperStepper(self.twin_model)
        stepper.warm_up()
        static = stepper.force_n
        RideSession.on_road(self.car, self.road.heights, 0, self.dt_s, static).warm_up()
        comp = Compensator(self.compensator_params, self.car, self.dt_s, static,
                           self.twin_model, self.road.heights)
        comp.reset(0.0, 0.0)
        comp.observe(0.0, 0.0, static)
        estimate = TransferEstimate(0.0055, 40.0, 0.7, 1.0)
        comp.demand(np.zeros(4), 0, estimate, estimate.delay_s, 1.0)
        tracker = TransferTracker(estimate, self.dt_s)
        tracker.push(0.0, 0.0)
        u = self._excitation
        identify(u, np.concatenate([np.zeros(5), u[:-5]]), self.dt_s,
                 self.compensator_params.max_delay_s)

    # -- state -------------------------------------------------------------------------
    @property
    def reason(self) -> str | None:
        """Why the run stopped (one line), or None."""
        return self.safety.reason if self.safety.reason is not None else self.failure

    @property
    def demand_m(self) -> float:
        """The latest stroke demand [m] (what a final command holds)."""
        return self._demand

    def stamp(self, t_ns: int) -> None:
        """The time [ns, the host's monotonic clock] the latest cycle's command was sent:
        the ride sample's ``t_monotonic_ns``."""
        if self.session is not None and self.k > 0 and self.t_ns[self.k - 1] == 0:
            self.t_ns[self.k - 1] = t_ns

    @property
    def finished(self) -> bool:
        return self.phase in ("done", "stopped")

    def _enter(self, phase: str, t_s: float) -> None:
        self.phase = phase
        self._phase_start_s = t_s

    def _elapsed(self, t_s: float) -> float:
        return t_s - (self._phase_start_s if self._phase_start_s is not None else t_s)

    def _toward(self, target_m: float) -> float:
        step = self.run.approach_speed_m_s * self.dt_s
        return min(max(target_m, self._demand - step), self._demand + step)

    # -- the cycle ---------------------------------------------------------------------
    def measure(self, t_s: float, feedback: Feedback) -> None:
        """A valid feedback received at ``t_s`` whose cycle has already run (it came
        late): the newest measurement for the next cycle; the safety layer checks it."""
        self._measured, self._force = feedback.stroke_m, feedback.force_n
        self._temperature = feedback.temperature_c
        self.safety.feedback(t_s, feedback.stroke_m, feedback.force_n)

    def cycle(self, t_s: float, feedback: Feedback | None, t_ns: int = 0) -> Command:
        """One cycle at ``t_s`` [s, the host's monotonic clock] with the newest valid
        feedback since the last cycle (None: none arrived); ``t_ns`` is recorded as the
        ride sample's send time.  Returns the command to send now."""
        safety = self.safety
        self.after_send()
        if self._start_s is None:
            self._start_s = t_s
            self._phase_start_s = t_s
        if feedback is not None:
            self.measure(t_s, feedback)
        safety.watchdog(t_s)
        if self.phase == "connect":
            if feedback is None:
                if t_s - self._start_s > self.run.connect_timeout_s:
                    self.failure = (f"no DYNO_FEEDBACK within {self.run.connect_timeout_s:g} s "
                                    "(is a dyno on the bus?)")
                    self.phase = "stopped"
                return Command(self._demand, 0.0, False)
            self._demand = feedback.stroke_m
            self._enter("settle", t_s)
        if not safety.enable and self.phase != "stopped":
            self.phase = "stopped"
        if self.phase == "stopped" or self.phase == "done":
            return Command(self._demand, 0.0, False)
        demand, velocity = getattr(self, "_" + self.phase)(t_s, feedback, t_ns)
        previous = self._demand
        self._demand = safety.clamp(demand, previous)
        if self.phase == "ride" and self.tracker is not None and self.k > 0:
            self.record[1, self.k - 1] = self._demand
            if self.compensator_params.adapt:
                self._pending = (self._demand, self._measured)
        return Command(self._demand, velocity, True)

    def after_send(self) -> None:
        """The cycle's work that can wait until its command is out: the tracker's update
        of the rig's delay and gain (the next cycle does it first if this is not called)."""
        if self._pending is not None and self.tracker is not None:
            self.tracker.push(*self._pending)
        self._pending = None

    def _settle(self, t_s: float, feedback: Feedback | None, t_ns: int) -> tuple[float, float]:
        if self._demand != 0.0:
            self._phase_start_s = t_s               # the hold starts at the position
            return self._toward(0.0), 0.0
        if self._elapsed(t_s) >= 0.5 * self.run.settle_s and math.isfinite(self._force):
            self._tare.append(self._force)
        if self._elapsed(t_s) >= self.run.settle_s and self._tare:
            self.static_force_n = float(np.mean(self._tare))
            self._enter("identify", t_s)
            self._j = 0
        return 0.0, 0.0

    def _identify(self, t_s: float, feedback: Feedback | None, t_ns: int
                  ) -> tuple[float, float]:
        j = self._j
        u = self._excitation
        if j >= u.size:
            self._enter("fit", t_s)
            self._fit_job = self.executor.submit(identify, self.identification[0],
                                             self.identification[1], self.dt_s,
                                             self.compensator_params.max_delay_s)
            return self._fit_poll(t_s)
        # the measurement received this cycle, and the demand then sent (the tracker's pairing)
        self.identification[:, j] = u[j], self._measured
        self._j = j + 1
        return float(u[j]), 0.0

    def _fit_poll(self, t_s: float) -> tuple[float, float]:
        assert self._fit_job is not None
        if not self._fit_job.done():
            return 0.0, 0.0
        try:
            estimate = self._fit_job.result()
        except Exception as exc:
            self.safety.stop(t_s, f"the transfer system's identification failed: {exc}")
            self.phase = "stopped"
            return 0.0, 0.0
        if not estimate.fit_nrms <= self.run.max_fit_nrms:
            self.safety.stop(t_s, f"the transfer system's identification fits the rig "
                                  f"{estimate.fit_nrms:.0%} r.m.s. (limit "
                                  f"{self.run.max_fit_nrms:.0%}): not the transfer system "
                                  "it models")
            self.phase = "stopped"
            return 0.0, 0.0
        self._start_ride(estimate, t_s)
        return self._ride_demand()

    def _fit(self, t_s: float, feedback: Feedback | None, t_ns: int) -> tuple[float, float]:
        return self._fit_poll(t_s)

    def _start_ride(self, estimate: TransferEstimate, t_s: float) -> None:
        p = self.compensator_params
        self.transfer = estimate
        self.tracker = TransferTracker(estimate, self.dt_s, p.adapt_window_s,
                                       p.adapt_period_s, p.max_delay_s)
        self.tracker.start(0.0)
        self.session = RideSession.on_road(self.car, self.road.heights, self.road.n_lead,
                                           self.dt_s, self.static_force_n)
        self.comp = Compensator(p, self.car, self.dt_s, self.static_force_n, self.twin_model,
                                self.road.heights)
        x, v = self.session.motion()
        self.comp.reset(x, v)
        self.twin.reset(self._measured, 0.0)
        self._enter("ride", t_s)
        self.k = 0

    def _ride_demand(self) -> tuple[float, float]:
        session, comp, tracker, est = self.session, self.comp, self.tracker, self.transfer
        assert session is not None and comp is not None and tracker is not None \
            and est is not None
        return comp.demand(session.car.state, session.k, est, tracker.delay_s, tracker.gain)

    def _ride(self, t_s: float, feedback: Feedback | None, t_ns: int) -> tuple[float, float]:
        session, comp = self.session, self.comp
        assert session is not None and comp is not None and self.tracker is not None
        k = session.k
        if k >= session.n:
            self._enter("return", t_s)
            return self._return(t_s, feedback, t_ns)
        x_m, force = self._measured, self._force
        x_t, v_t = session.motion()
        comp.observe(x_t, v_t, force)
        session.apply(force)
        self.safety.tracking(t_s, x_m - x_t, float(self.reference.damper_stroke_m[k]))
        rec = self.record
        rec[0, k] = x_t
        rec[2, k] = x_m
        rec[3, k] = force
        rec[5, k] = 1.0
        self.t_ns[k] = t_ns
        self.delay_estimate_s[k] = self.tracker.delay_s
        self.temperature_c[k] = self._temperature
        # the twin one sample behind, at the central difference of the measured stroke
        x1, x2 = self._prev_measured
        if k >= 1 and math.isfinite(x2):
            force_model, _ = self.twin.step(x1, (x_m - x2) / (2.0 * self.dt_s), self.dt_s)
            rec[4, k - 1] = force_model
        self._prev_measured = (x_m, x1)
        self.k = k + 1
        if not self.safety.enable:
            return self._demand, 0.0
        return self._ride_demand()

    def _return(self, t_s: float, feedback: Feedback | None, t_ns: int) -> tuple[float, float]:
        if self._demand == 0.0 and self._elapsed(t_s) > 0.1:
            self.phase = "done"
        return self._toward(0.0), 0.0

    # -- the outcome -------------------------------------------------------------------
    def ride_result(self) -> RideResult:
        """The car's histories over the samples ridden."""
        assert self.session is not None
        return self.session.result("hybrid")

    def ride_metrics(self) -> dict[str, float] | None:
        """The ride's metrics over the evaluated part, None when the ride stopped before
        its end."""
        if self.session is None or self.session.k < self.road.evaluated.stop:
            return None
        sl = self.road.evaluated
        return metrics(self.ride_result(), sl.start, sl.stop)


def export_measured(host: HybridHost, path: Path) -> Path | None:
    """The ride as a measured-data CSV (docs/interfaces.md §2): ``time``, ``displacement``
    (the measured stroke), ``velocity`` (its central difference), ``force`` (measured) and,
    when the dyno reported it, ``temperature``: held-out data for ``validate`` and
    ``diagnose``.  None when no ride sample was recorded."""
    k = host.k
    if k < 3:
        return None
    x = host.record[2, :k]
    t = np.arange(k) * host.dt_s
    temperature = host.temperature_c[:k]
    return write_measured_csv(path, t, x, host.record[3, :k], np.gradient(x, host.dt_s),
                              temperature if np.isfinite(temperature).all() else None)
