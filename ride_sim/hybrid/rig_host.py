"""The host's side of a rig run, one cycle per dyno cycle, free of any bus.

:class:`RigHost` holds what every run of a physical damper on a CAN dyno shares: the
phases before and after the run proper, the safety layer, the transfer system's
identification and tracker, and the record.  :class:`~ride_sim.hybrid.host.HybridHost`
(the quarter car drives the dyno) and :class:`~ride_sim.hybrid.protocol_host.ProtocolHost`
(a dyno protocol) are its two runs.  It is called once per rig cycle with the newest valid
``DYNO_FEEDBACK`` (or ``None`` when none came) and returns the ``DYNO_COMMAND`` to send:

``connect``
    ``Enable`` clear until the dyno's first feedback (none within ``connect_timeout_s``:
    the run fails, :attr:`RigHost.failure`).
``settle``
    Enabled, the demand moves from where the rig stands to the static position at
    ``approach_speed_m_s`` and holds there ``settle_s``; the force's mean over the hold's
    second half is the static force (the tare).
``identify``, ``fit``
    The low-amplitude test signal (:func:`~ride_sim.hybrid.transfer.excitation`), then
    the fit of the transfer system (:func:`~ride_sim.hybrid.transfer.identify`; run by the
    ``executor`` given, the demand held at the static position meanwhile).  A cycle that
    a stall of the host or the bus disturbed (:data:`STALL_CYCLES`) is left out of the fit
    with ``stall_guard_s`` after it; while the fit misses ``max_fit_nrms``, or stalls
    leave less than :data:`MIN_USABLE_SHARE` of the cycles, the signal runs again, up to
    ``identify_attempts`` in all (:attr:`RigHost.attempts` holds each one's account).
the run proper (:attr:`RigHost.RUN_PHASE`)
    The subclass's.
``return``, ``done``
    The demand returns to the static position; ``Enable`` is cleared.
``stopped``
    The safety layer stopped the run (:mod:`ride_sim.hybrid.safety`): ``Enable`` clear,
    the demand held; :attr:`RigHost.reason` says why.
``rearm``
    The watchdog or a stall of the host stopped the run before the run proper (a stop
    of the timing, not one of the specimen's limits): ``Enable`` clear for
    ``watchdog_s`` (the rig's own watchdog has tripped by then too), then ``connect``
    again with a new safety layer and a new identification, up to ``restarts`` times
    (:attr:`RigHost.restarts` holds each one's account).  Nothing has been ridden or
    tested yet, so nothing is lost but time; in the run proper a stop is final.

Every demand passes :meth:`~ride_sim.hybrid.safety.SafetyLayer.clamp`, in every phase.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from damper_emulator.dyno.formats import DEFAULT_FORMAT, write_measured
from damper_emulator.errors import DamperHilError
from damper_emulator.realtime.worker import Executor, OffLoopWorker, Pending
from ride_sim.hybrid.params import CompensatorParams, HybridRunParams, SafetyParams
from ride_sim.hybrid.rig import Feedback
from ride_sim.hybrid.safety import SafetyLayer
from ride_sim.hybrid.transfer import (
    NOMINAL_ESTIMATE,
    TransferEstimate,
    TransferTracker,
    excitation,
    identify,
    response,
    stall_count,
    usable_cycles,
)

#: The host's cycle: one per cycle of a dyno at 1 kHz [s] (the hosts' default ``dt_s``).
HOST_CYCLE_S = 1e-3
#: A cycle whose feedback has not come this many periods after the last runs without it
#: (the link's read times out; :mod:`ride_sim.hybrid.offline` models it).
MISSED_FEEDBACK_PERIODS = 1.5
#: A cycle that ran without its feedback takes it when it comes, placed by the dyno's alive
#: counter (4 bits: the DBC's ``Counter``): at most this many cycles minus one after it ran
#: (:meth:`RigHost.late`).  A record written while the run goes on holds back this many of
#: the newest samples: they may still change.
LATE_CYCLES = 16
#: A stall, in the identification [cycles]: a fresh feedback more than this many cycles
#: later than a cycle after the last fresh one, or a command sent more than this many cycles
#: after its feedback arrived.  Shorter jitter stays in the fit: it moves the demand the rig
#: took by three cycles at most, and leaving it out (with its guard) left out most of an
#: identification on this project's 2-core VM, whose host runs cycles without feedback
#: (1.5 cycles late) in 1 % to 17 % of them, for fits no better.
STALL_CYCLES = 3.0
#: An identification whose stalls leave less than this share of its cycles is run again
#: without a fit [-].
MIN_USABLE_SHARE = 0.5
#: Rows of a run's record (:attr:`RigHost.record`), in ``hybrid.csv``'s order after
#: ``t_monotonic_ns`` and ``time``.
RECORD_COLUMNS = ("stroke_target", "stroke_command", "stroke_measured", "force_measured",
                  "force_model", "enable")


class Command(NamedTuple):
    """One ``DYNO_COMMAND``."""

    stroke_m: float
    velocity_m_s: float
    enable: bool


#: The phases every run has, in order (``stopped`` may follow any); the run proper's
#: (:attr:`RigHost.RUN_PHASE`) comes after ``fit``, and a subclass may add its own
#: (:attr:`RigHost.OWN_PHASES`).
PHASES = ("connect", "settle", "identify", "fit", "return", "done", "stopped", "rearm")


class _Immediate:
    """An executor that runs the work at once (offline runs, tests)."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future[Any]:
        future: Future[Any] = Future()
        try:
            future.set_result(fn(*args))
        except Exception as exc:  # noqa: BLE001 - handed to the caller through the future
            future.set_exception(exc)
        return future


def fit_worker(name: str) -> OffLoopWorker:
    """The process a run's identification fit runs in (:class:`RigHost`'s ``executor``),
    started now: its own, off the loop's GIL, and it imports the fit's modules as it
    starts."""
    return OffLoopWorker(name, preload=(__name__,))


def _fit_and_tracker(demand: np.ndarray, measured: np.ndarray, dt_s: float,
                     p: CompensatorParams, usable: np.ndarray
                     ) -> tuple[TransferEstimate, TransferTracker]:
    """The identification's fit and the tracker that follows its delay and gain, made
    off the loop: the tracker's discretised servo (a matrix exponential) took tens of
    milliseconds in a cycle on a loaded machine."""
    estimate = identify(demand, measured, dt_s, p.max_delay_s, usable)
    return estimate, TransferTracker(estimate, dt_s, p.adapt_window_s, p.adapt_period_s,
                                     p.max_delay_s)


class RigHost:
    """The phases every rig run shares (see the module docstring).

    Parameters
    ----------
    run : HybridRunParams
        The run's settle, approach, connect and identification-fit settings.
    compensator : CompensatorParams
    safety : SafetyParams
    dt_s : float
        The rig's cycle [s] (the host runs once per feedback).
    samples : int
        Cycles of the run proper (the record's length).
    executor : Executor, optional
        Runs the identification's fit off the loop: an
        :class:`~damper_emulator.realtime.worker.OffLoopWorker`, whose process does not
        share the loop's GIL (default: at once, in the cycle).
    """

    #: the name of the run proper's phase
    RUN_PHASE = "run"
    #: the subclass's phases besides the run proper and :data:`PHASES`
    OWN_PHASES: tuple[str, ...] = ()

    def __init__(self, run: HybridRunParams, compensator: CompensatorParams,
                 safety: SafetyParams, dt_s: float, samples: int,
                 executor: Executor | None = None) -> None:
        self.run = run
        self.compensator_params = compensator
        self.dt_s = float(dt_s)
        self.safety = SafetyLayer(safety, dt_s)
        self.executor: Executor = executor if executor is not None else _Immediate()
        self.phase = "connect"
        self.failure: str | None = None
        self._phase_start_s: float | None = None
        self._start_s: float | None = None
        self._demand = 0.0
        self._measured = math.nan
        self._force = math.nan
        self._temperature = math.nan
        self._tare: list[float] = []
        self.static_force_n = math.nan
        self._excitation = excitation(compensator.identify_s, dt_s,
                                      compensator.identify_amplitude_m,
                                      compensator.identify_band_hz, seed=run.seed)
        self.identification = np.full((2, self._excitation.size), np.nan)
        #: the identification's cycles a stall disturbed (the latest attempt's)
        self.disturbed = np.zeros(self._excitation.size, dtype=bool)
        #: the cycles the latest attempt's fit compared
        self.usable = np.ones(self._excitation.size, dtype=bool)
        #: each identification attempt's account (:meth:`identification_report`)
        self.attempts: list[dict[str, Any]] = []
        self._attempts_from = 0     # the current start's first attempt in attempts
        #: each restart's account (:meth:`_restart`): the phase and the stop's reason
        self.restarts: list[dict[str, Any]] = []
        #: feedback stamped before this [s, monotonic] is stale: the frames that waited in
        #: the socket through the stall that began the last restart
        self._stale_before_s = -math.inf
        self._last_fresh_s: float | None = None
        self._cycle_s = math.nan
        self._stalled = False
        self._j = 0
        self._fit_job: Pending[tuple[TransferEstimate, TransferTracker]] | None = None
        self.transfer: TransferEstimate | None = None
        self.tracker: TransferTracker | None = None
        n = int(samples)
        self.record = np.full((len(RECORD_COLUMNS), n), np.nan)
        self.t_ns = np.zeros(n, dtype=np.int64)
        self.delay_estimate_s = np.full(n, np.nan)
        #: the dyno's latest oil temperature (DYNO_AUX) at each sample of the run [°C]
        self.temperature_c = np.full(n, np.nan)
        #: the run's samples a stall disturbed (as the identification's: :data:`STALL_CYCLES`)
        self.stalled = np.zeros(n, dtype=bool)
        #: the run's samples measured in their own cycle: its feedback came (in time, or
        #: late and put in its place by :meth:`late`); the others hold the last measurement
        self.fresh = np.zeros(n, dtype=bool)
        #: of those, the samples whose feedback came after their cycle had run
        self.placed_late = 0
        self._fresh_now = False
        #: the longest stall the host saw, in any phase [s]
        self.longest_stall_s = 0.0
        self._pending: tuple[float, float] | None = None
        self._cycles = 0            # cycles run: the rig's cycles, lost frames included
        #: the run proper's cycles held as a stall's backlog (:meth:`_hold`)
        self.held_cycles = 0
        self._after_hold = False
        self._backlog_from: float | None = None
        self.k = 0

    def warm_up(self) -> None:
        """Run once what the cycle's tracker and the identification's model use before the
        loop's clock starts (the fit itself runs off the loop, on the executor)."""
        response(self._excitation, self.dt_s, NOMINAL_ESTIMATE)
        TransferTracker(NOMINAL_ESTIMATE, self.dt_s).push(0.0, 0.0)

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
        the run's sample's ``t_monotonic_ns``; in the identification, a command sent late
        marks its cycle disturbed."""
        late = t_ns * 1e-9 - self._cycle_s
        self.longest_stall_s = max(self.longest_stall_s, late)
        if late > STALL_CYCLES * self.dt_s:
            if self.phase == "identify" and self._j > 0:
                self.disturbed[self._j - 1] = True
            elif self.phase == self.RUN_PHASE and self.k > 0:
                self.stalled[self.k - 1] = True
        if self.k > 0 and self.t_ns[self.k - 1] == 0:
            self.t_ns[self.k - 1] = t_ns

    @property
    def stall_guard_cycles(self) -> int:
        """``stall_guard_s`` in cycles: left out after a stall's cycles."""
        return int(round(self.compensator_params.stall_guard_s / self.dt_s))

    @property
    def finished(self) -> bool:
        return self.phase in ("done", "stopped")

    def _enter(self, phase: str, t_s: float) -> None:
        phases = (*PHASES, self.RUN_PHASE, *self.OWN_PHASES)
        if phase not in phases:          # a bug: each phase has its step method
            raise DamperHilError(f"hybrid: no phase {phase!r} (phases: {', '.join(phases)})")
        self.phase = phase
        self._phase_start_s = t_s

    def _elapsed(self, t_s: float) -> float:
        return t_s - (self._phase_start_s if self._phase_start_s is not None else t_s)

    def _toward(self, target_m: float) -> float:
        step = self.run.approach_speed_m_s * self.dt_s
        return min(max(target_m, self._demand - step), self._demand + step)

    # -- the cycle ---------------------------------------------------------------------
    def measure(self, t_s: float, feedback: Feedback, cycles_back: int = 0) -> None:
        """A valid feedback received at ``t_s``, of the cycle ``cycles_back`` cycles before
        the latest: the newest measurement for the next cycle; the safety layer checks it
        (its velocity over the cycles the frame's really are).  Feedback stamped before
        the last restart is stale (:meth:`_restart`) and left out."""
        if t_s < self._stale_before_s:
            return
        self._measured, self._force = feedback.stroke_m, feedback.force_n
        self._temperature = feedback.temperature_c
        self.safety.feedback(t_s, feedback.stroke_m, feedback.force_n,
                             self._cycles - int(cycles_back))

    def late(self, t_s: float, feedback: Feedback, cycles_back: int) -> None:
        """A valid feedback received at ``t_s`` for a cycle that already ran on the last
        measurement, ``cycles_back`` cycles before the latest (the dyno's alive counter
        says which): the newest measurement for the next cycle (:meth:`measure`), and in
        the run proper the measurement of that cycle's sample, in its place."""
        self.measure(t_s, feedback, cycles_back)
        if self.phase != self.RUN_PHASE:     # (a restart's stale frames among them)
            return
        k = self.k - 1 - int(cycles_back)
        if 0 <= k < self.fresh.size and not self.fresh[k]:
            self.record[2, k], self.record[3, k] = feedback.stroke_m, feedback.force_n
            self.temperature_c[k] = feedback.temperature_c
            self.fresh[k] = True
            self.placed_late += 1

    def cycle(self, t_s: float, feedback: Feedback | None, t_ns: int = 0,
              now_s: float | None = None) -> Command:
        """One cycle at ``t_s`` [s, the host's monotonic clock] with the newest valid
        feedback since the last cycle (None: none arrived); ``t_ns`` is recorded as the
        run's sample's send time.  ``now_s``: when the host runs the cycle (default
        ``t_s``); a cycle run more than :data:`STALL_CYCLES` after its feedback came is one
        of a stall's backlog, which the run proper holds (:meth:`_hold`).  Returns the
        command to send now."""
        safety = self.safety
        now = t_s if now_s is None else now_s
        if feedback is not None and t_s < self._stale_before_s:
            feedback = None
        self._cycles += 1
        self.after_send()
        self._watch_stall(t_s, feedback is not None)
        self._fresh_now = feedback is not None
        if self._start_s is None:
            self._start_s = t_s
            self._phase_start_s = t_s
        if feedback is not None:
            self.measure(t_s, feedback)
        if self.phase != "rearm":
            # (in rearm Enable is clear and the host waits out the rig's watchdog: a gap
            # in the feedback there is no stop; the new safety layer's starts at connect)
            safety.watchdog(t_s)
        if not safety.enable and self._may_restart():
            self._restart(t_s, now)
            safety = self.safety
        if self.phase == "rearm":
            # by the host's clock: the cycles that drain the stall's backlog run on the
            # frames' stamps, from before the restart
            if self._elapsed(now) >= safety.params.watchdog_s:
                safety.await_feedback()
                self._enter("connect", now)
            return Command(self._demand, 0.0, False)
        if self.phase == "connect":
            if feedback is None:
                if self._elapsed(t_s) > self.run.connect_timeout_s:
                    self._connect_timed_out(t_s)
                return Command(self._demand, 0.0, False)
            self._demand = feedback.stroke_m
            self._enter("settle", t_s)
        if not safety.enable and self.phase != "stopped":
            self.phase = "stopped"
        if self.phase == "stopped" or self.phase == "done":
            return Command(self._demand, 0.0, False)
        if self.phase == self.RUN_PHASE:
            if self._holds(t_s, now_s):
                demand, velocity = self._hold()
            else:
                demand, velocity = self._run_cycle(t_s, t_ns)
                if self._after_hold:
                    self._after_hold = False
                    self.stalled[self.k - 1] = True
        else:
            demand, velocity = getattr(self, "_" + self.phase)(t_s, feedback, t_ns)
        previous = self._demand
        self._demand = safety.clamp(demand, previous)
        if self.phase == self.RUN_PHASE and self.tracker is not None and self.k > 0:
            self.record[1, self.k - 1] = self._demand
            if self.compensator_params.adapt:
                self._pending = (self._demand, self._measured)
        return Command(self._demand, velocity, True)

    def _connect_timed_out(self, t_s: float) -> None:
        """No feedback within ``connect_timeout_s``: no dyno at the start (a failure), or,
        after a restart, the stop that began it stands (the rig has not come back)."""
        wait = f"no DYNO_FEEDBACK within {self.run.connect_timeout_s:g} s"
        if self.restarts:
            self.safety.stop(t_s, f"{self.restarts[-1]['reason']}; {wait} of the restart",
                             timing=True)
        else:
            self.failure = f"{wait} (is a dyno on the bus?)"
        self.phase = "stopped"

    def _may_restart(self) -> bool:
        """Whether the safety layer's stop may start the run again (:meth:`_restart`)."""
        return (self.safety.timing and len(self.restarts) < self.run.restarts
                and self.phase not in (self.RUN_PHASE, "return", "done", "stopped"))

    def _restart(self, t_s: float, now_s: float) -> None:
        """The watchdog or a stall of the host stopped the run before the run proper
        (the cycle of ``t_s``, run at ``now_s``): account for it, take a new safety layer
        (its demands' clamp count carried over) and forget the start (tare,
        identification, transfer system), then ``rearm``.

        The feedback stamped before ``now_s`` is left out from now on: the frames that
        waited in the socket through a stall of the host are stale, and where the
        socket's buffer overflowed they end in a gap (the newest frames were dropped)
        that the new safety layer's watchdog would take for the rig's silence."""
        old = self.safety
        self.restarts.append({"phase": self.phase, "reason": old.reason,
                              "at_s": t_s - (self._start_s or t_s)})
        self.safety = SafetyLayer(old.params, self.dt_s)
        self.safety.clamped = old.clamped
        self._tare = []
        self._j = 0
        self.identification[:] = np.nan
        self.disturbed[:] = False
        self._fit_job = None
        self.transfer = None
        self.tracker = None
        self._attempts_from = len(self.attempts)
        self._stale_before_s = now_s
        self._enter("rearm", now_s)

    def _watch_stall(self, t_s: float, fresh: bool) -> None:
        """Whether this cycle comes after a stall: :data:`STALL_CYCLES` or more later than a
        cycle after the last fresh feedback."""
        last = self._last_fresh_s
        behind = 0.0 if last is None else t_s - last - self.dt_s
        self.longest_stall_s = max(self.longest_stall_s, behind)
        self._stalled = behind > STALL_CYCLES * self.dt_s
        if fresh:
            self._last_fresh_s = t_s
        self._cycle_s = t_s

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
            return self._submit_fit(t_s)
        # the measurement received this cycle, and the demand then sent (the tracker's pairing)
        self.identification[:, j] = u[j], self._measured
        self.disturbed[j] = self._stalled
        self._j = j + 1
        return float(u[j]), 0.0

    def _submit_fit(self, t_s: float) -> tuple[float, float]:
        """The signal has run: fit it on its usable cycles, or run it again when stalls
        left too few."""
        p = self.compensator_params
        self.usable = usable_cycles(self.disturbed, self.stall_guard_cycles)
        if np.mean(self.usable) < MIN_USABLE_SHARE:
            self._account(None)
            return self._again_or_stop(t_s, f"kept {np.mean(self.usable):.0%} of its cycles "
                                            f"from stalls (at least {MIN_USABLE_SHARE:.0%})")
        self._enter("fit", t_s)
        self._fit_job = self.executor.submit(_fit_and_tracker, self.identification[0],
                                             self.identification[1], self.dt_s, p,
                                             self.usable)
        return self._fit_poll(t_s)

    def _account(self, estimate: TransferEstimate | None) -> None:
        """Add the attempt just ended to :attr:`attempts`."""
        d = self.disturbed
        self.attempts.append({
            "fit_nrms": None if estimate is None else estimate.fit_nrms,
            "stalls": stall_count(d),
            "disturbed_cycles": int(np.count_nonzero(d)),
            "left_out": float(1.0 - np.mean(self.usable))})

    def _again_or_stop(self, t_s: float, why: str) -> tuple[float, float]:
        """Run the identification again, or stop the run when its attempts are spent."""
        tries = len(self.attempts) - self._attempts_from
        if tries >= self.compensator_params.identify_attempts:
            self.safety.stop(t_s, f"the transfer system's identification {why} "
                                  f"(attempt {tries} of {tries})")
            self.phase = "stopped"
            return 0.0, 0.0
        self._enter("identify", t_s)
        self._j = 0
        self.identification[:] = np.nan
        self.disturbed[:] = False
        return 0.0, 0.0

    def identification_report(self) -> dict[str, Any]:
        """The identification's attempts and what stalls left out of each (``hybrid.json``'s
        ``identification``)."""
        return {"attempts": len(self.attempts), "each": list(self.attempts),
                "guard_ms": self.compensator_params.stall_guard_s * 1e3,
                "restarts": list(self.restarts)}

    def _fit_poll(self, t_s: float) -> tuple[float, float]:
        assert self._fit_job is not None
        if not self._fit_job.done():
            return 0.0, 0.0
        try:
            estimate, tracker = self._fit_job.result()
        except Exception as exc:  # noqa: BLE001 - any failed fit stops the ride safely
            self.safety.stop(t_s, f"the transfer system's identification failed: {exc}")
            self.phase = "stopped"
            return 0.0, 0.0
        self._account(estimate)
        if not estimate.fit_nrms <= self.run.max_fit_nrms:
            return self._again_or_stop(t_s, f"fits the rig {estimate.fit_nrms:.0%} r.m.s. "
                                            f"(limit {self.run.max_fit_nrms:.0%}): not the "
                                            "transfer system it models")
        self.transfer = estimate
        self.tracker = tracker
        self.tracker.start(self._demand)
        return self._after_fit(t_s)

    def _fit(self, t_s: float, feedback: Feedback | None, t_ns: int) -> tuple[float, float]:
        return self._fit_poll(t_s)

    def _return(self, t_s: float, feedback: Feedback | None, t_ns: int) -> tuple[float, float]:
        if self._demand == 0.0 and self._elapsed(t_s) > 0.1:
            self.phase = "done"
        return self._toward(0.0), 0.0


    # -- the run proper: the subclass's ------------------------------------------------
    def _after_fit(self, t_s: float) -> tuple[float, float]:
        """The transfer system is known (:attr:`transfer`, :attr:`tracker`): start the
        run proper (or what leads to it) and return this cycle's demand and rate."""
        raise NotImplementedError

    def _run_cycle(self, t_s: float, t_ns: int) -> tuple[float, float]:
        """One cycle of the run proper: record sample :attr:`k`, advance it, and return
        the demand and its rate (entering ``return`` after the last sample)."""
        raise NotImplementedError

    def _holds(self, t_s: float, now_s: float | None) -> bool:
        """Whether this cycle of the run proper is held (:meth:`_hold`): one of a stall's
        backlog (run more than :data:`STALL_CYCLES` after its feedback came) whose
        feedback came a transport delay (the tracker's) or more after the backlog's
        first.  Until then the rig still ran on the demands it had been sent, and its
        feedback is the run's motion; after, it stood."""
        behind = 0.0 if now_s is None else now_s - t_s
        if behind <= STALL_CYCLES * self.dt_s:
            self._backlog_from = None
            return False
        if self._backlog_from is None:
            self._backlog_from = t_s
        assert self.tracker is not None
        return self.k > 0 and t_s - self._backlog_from >= self.tracker.delay_s

    def _hold(self) -> tuple[float, float]:
        """A cycle of a stall's backlog in the run proper (:meth:`_holds`): the demand
        held, no sample.

        While the host stalled, the rig had no command: once through the demands it had,
        it held the last one, and its cycles that waited for the host are the rig at rest,
        not the run's motion.  Run as samples, they would step the run on that force (the
        quarter car takes the damper's force without its damping) and put the next demand
        a stall's worth of motion ahead of where the rig stands: an error burst that grows
        with the stall (offline, a 30 ms stall: up to 7.7 mm).  Held, the run resumes where the rig
        stopped, a stall later, and the error is the servo's start from rest, whatever
        the stall's length; the sample after the hold is marked stalled.  The tracker
        still takes the cycle (held demand, measurement): that is what the rig was given
        and did."""
        self._after_hold = True
        self.held_cycles += 1
        return self._demand, 0.0

    def _record_sample(self, k: int, target_m: float, t_ns: int) -> None:
        """Sample ``k``'s target, measurement and state (the demand follows after the
        safety layer's clamp)."""
        rec = self.record
        rec[0, k] = target_m
        rec[2, k] = self._measured
        rec[3, k] = self._force
        rec[5, k] = 1.0
        self.stalled[k] = self._stalled
        self.fresh[k] = self._fresh_now
        self.t_ns[k] = t_ns
        assert self.tracker is not None
        self.delay_estimate_s[k] = self.tracker.delay_s
        self.temperature_c[k] = self._temperature


def measured_samples(host: RigHost) -> np.ndarray:
    """The indices of the run's samples that were measured in their own cycle
    (:attr:`RigHost.fresh`): a cycle run without its feedback (lost, or the host's wait
    timed out and it never came) holds the last measurement, which is not that cycle's."""
    return np.flatnonzero(host.fresh[:host.k])


def export_measured(host: RigHost, path: Path, fmt: str = DEFAULT_FORMAT) -> list[Path]:
    """The run's measured samples (:func:`measured_samples`) as measured data
    (docs/interfaces.md §2; CSV, MDF4 or both by ``fmt``,
    :mod:`~damper_emulator.dyno.formats`): ``time`` (the sample's cycle times the rig's
    period), ``displacement`` (the measured stroke), ``velocity`` (its derivative),
    ``force`` (measured) and, when the dyno reported it, ``temperature``: held-out data for
    ``validate`` and ``diagnose``.  A cycle without its own measurement is left out, not
    held.  Nothing (an empty list) when fewer than 3 samples of the run proper were
    measured."""
    k = measured_samples(host)
    if k.size < 3:
        return []
    x = host.record[2, k]
    t = k * host.dt_s
    temperature = host.temperature_c[k]
    return write_measured(path, fmt, t, x, host.record[3, k], np.gradient(x, t),
                          temperature if np.isfinite(temperature).all() else None,
                          comment="damper-hil hybrid: the damper's measured samples")


#: the record's channels in an MDF4 file (``RECORD_COLUMNS`` by name): unit, comment
RECORD_MDF = {
    "stroke_target": ("m", "the quarter car's damper stroke (the target)"),
    "stroke_command": ("m", "the stroke demand sent to the dyno (lag compensated)"),
    "stroke_measured": ("m", "the dyno's measured stroke"),
    "force_measured": ("N", "the dyno's measured force, rebound positive"),
    "force_model": ("N", "the twin's force on the measured motion"),
}


def export_record_mdf(host: RigHost, path: Path) -> Path:
    """The run's record (what ``hybrid.csv`` holds) as an MDF4 file: time [s] from the
    ride's start, ``t_monotonic`` (the host's clock when the command went: raw ns, shown
    in s), the strokes and forces, ``enable`` (a state: ``disabled``/``enabled``)."""
    from damper_emulator.dyno.mdf_writer import MdfChannel, MdfGroup, write_mdf

    k = host.k
    channels = [MdfChannel("t_monotonic", host.t_ns[:k].copy(), "s",
                           "CLOCK_MONOTONIC when the command was sent", linear=(1e-9, 0.0))]
    channels += [MdfChannel(name, host.record[RECORD_COLUMNS.index(name), :k].copy(), unit,
                            comment) for name, (unit, comment) in RECORD_MDF.items()]
    enable = np.nan_to_num(host.record[RECORD_COLUMNS.index("enable"), :k]).astype(np.uint8)
    channels.append(MdfChannel("enable", enable, "", "the dyno's drive enable",
                               states={0: "disabled", 1: "enabled"}))
    return write_mdf(path, [MdfGroup(np.arange(k) * host.dt_s, channels,
                                     "the hybrid ride, one sample per dyno cycle")],
                     "damper-hil hybrid: a physical damper in the quarter car's loop")
