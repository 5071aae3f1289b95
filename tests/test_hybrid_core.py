"""The cores of the damper in the loop (ride_sim.hybrid), without a bus.

The actuator against closed forms; the identification against rigs of known transfer
systems; the safety layer on its own; the loop (host + virtual rig on a simulated timeline)
against the all-numerical reference and through a rig's disturbances (a doubled delay, a
feedback cut, lost frames, an unstable setting, a thermal fade).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config, with_extensions
from ride_sim.hybrid.actuator import DelayLine, Servo, frequency_response
from ride_sim.hybrid.compensator import force_path_gain
from ride_sim.hybrid.host import RIDE_KEYS, HybridHost
from ride_sim.hybrid.offline import Disturbance, run_offline
from ride_sim.hybrid.params import (
    ActuatorParams,
    CompensatorParams,
    HybridRunParams,
    RigParams,
    SafetyParams,
    build,
)
from ride_sim.hybrid.rig import STATUS_AT_LIMIT, STATUS_ENABLED, Feedback, VirtualRig
from ride_sim.hybrid.safety import WATCHDOG_TRIP, SafetyLayer
from ride_sim.hybrid.transfer import TransferEstimate, excitation, identify
from ride_sim.params import load_quarter_car

DT = 1e-3


@pytest.fixture(scope="module")
def model() -> DamperModel:
    return DamperModel()


# -- the actuator ----------------------------------------------------------------------

def test_servo_step_response_is_the_second_order_closed_form():
    p = ActuatorParams(bandwidth_hz=40.0, damping=0.7)
    servo = Servo(p)
    w, z = 2 * math.pi * 40.0, 0.7
    wd = w * math.sqrt(1 - z * z)
    phi = math.acos(z)
    for k in range(1, 101):
        x, _ = servo.step(1.0, DT)
        t = k * DT
        exact = 1 - math.exp(-z * w * t) * math.sin(wd * t + phi) / math.sqrt(1 - z * z)
        assert x == pytest.approx(exact, abs=1e-12)


def test_delay_line_gives_the_demand_in_effect_a_delay_after_it_arrived():
    line = DelayLine(0.004, initial=-1.0)
    line.push(0.0, 1.0)
    line.push(0.001, 2.0)
    assert line.at(0.0039) == -1.0
    assert line.at(0.004) == 1.0
    assert line.at(0.0049) == 1.0
    assert line.at(0.005) == 2.0


def test_delay_line_moves_a_demand_on_at_its_rate_for_the_horizon_only():
    line = DelayLine(0.004, horizon_s=0.002)
    line.push(0.0, 1.0, rate=10.0)
    assert line.at(0.0045) == pytest.approx(1.0 + 10.0 * 0.0005, abs=1e-12)
    assert line.at(0.1) == pytest.approx(1.0 + 10.0 * 0.002, abs=1e-12)   # no further
    line.push(0.2, 3.0)                                                     # rate 0: held
    assert line.at(0.3) == 3.0


def test_virtual_rig_lags_a_sine_as_its_transfer_function_says(model):
    act = ActuatorParams(delay_s=0.004, bandwidth_hz=40.0, damping=0.7)
    rig = VirtualRig(model, act, RigParams(force_noise_n=0.0, stroke_noise_m=0.0))
    f = 5.0
    n = 3000
    u = 0.005 * np.sin(2 * np.pi * f * np.arange(n) * DT)
    x = np.empty(n)
    for k in range(n):
        rig.command(k * DT, u[k], True)
        x[k] = rig.step(k * DT).stroke_m
    tail = slice(1000, n)
    e = np.exp(-2j * np.pi * f * np.arange(n)[tail] * DT)
    measured = (x[tail] @ e) / (u[tail] @ e)
    # the rig samples the demand each cycle and holds it over the cycle (zero-order hold:
    # sinc(f T) e^(−jω T/2)); it measures the servo's state at the cycle's start
    expected = frequency_response(act, f) * np.exp(-1j * np.pi * f * DT) * np.sinc(f * DT)
    assert abs(measured) == pytest.approx(abs(expected), rel=2e-3)
    assert np.angle(measured / expected) == pytest.approx(0.0, abs=2e-3)


def test_virtual_rig_stops_at_its_travel_and_holds_without_commands(model):
    rig = VirtualRig(model, ActuatorParams(delay_s=0.0), RigParams(travel_m=0.01))
    for k in range(300):
        rig.command(k * DT, 0.05, True)
        fb = rig.step(k * DT)
    assert fb.status & STATUS_AT_LIMIT and fb.status & STATUS_ENABLED
    assert rig.servo.stroke_m <= 0.01
    held = rig.servo.stroke_m
    for k in range(300, 400):                 # no command: hold after hold_after_s
        fb = rig.step(k * DT)
    assert not fb.status & STATUS_ENABLED
    assert abs(rig.servo.stroke_m - held) < 1e-4


# -- identification and tracking ---------------------------------------------------------

def _identification_run(model, act):
    rig = VirtualRig(model, act, RigParams())
    u = excitation(3.0, DT, 1e-3, seed=3)
    x = np.empty(u.size)
    for k in range(u.size):
        x[k] = rig.step(k * DT).stroke_m           # received, then the demand sent
        rig.command(k * DT + 0.5e-3, u[k], True)
    return u, x


@pytest.mark.parametrize(("delay_ms", "bandwidth", "damping"), [(4.0, 40.0, 0.7),
                                                           (9.0, 20.0, 0.4),
                                                           (2.0, 80.0, 1.0)])
def test_identify_recovers_the_rigs_transfer_system(model, delay_ms, bandwidth, damping):
    act = ActuatorParams(delay_s=delay_ms * 1e-3, bandwidth_hz=bandwidth, damping=damping,
                         gain=0.97)
    est = identify(*_identification_run(model, act), DT)
    # the demand sent at cycle k reaches the rig half a cycle later, acts from the first
    # rig cycle a delay after that and shows in the measurement of the cycle after:
    # the pure delay is the transport delay rounded up to whole cycles
    assert est.delay_s == pytest.approx(math.ceil(delay_ms + 0.5) * 1e-3, abs=0.15e-3)
    assert est.bandwidth_hz == pytest.approx(bandwidth, rel=0.05)
    assert est.damping == pytest.approx(damping, rel=0.05)
    assert est.gain == pytest.approx(0.97, rel=0.01)
    assert est.fit_nrms < 0.05


def test_identify_refuses_a_rig_that_does_not_move():
    u = excitation(2.0, DT, 1e-3)
    with pytest.raises(Exception, match="did not follow"):
        identify(u, np.zeros_like(u), DT)


# -- the safety layer ----------------------------------------------------------------------

@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=1,
                max_size=200))
def test_no_demand_ever_leaves_the_limits(demands):
    p = SafetyParams(stroke_limit_m=0.05, velocity_limit_m_s=1.0)
    safety = SafetyLayer(p, DT)
    previous = 0.0
    for d in demands:
        value = safety.clamp(d, previous)
        assert abs(value) <= p.stroke_limit_m
        assert abs(value - previous) <= p.velocity_limit_m_s * DT * (1 + 1e-12)
        previous = value


def test_watchdog_clears_enable_within_its_time_of_the_last_valid_feedback():
    safety = SafetyLayer(SafetyParams(watchdog_s=0.05), DT)
    safety.feedback(1.0, 0.0, 0.0)
    t = 1.0
    while safety.enable:
        t += DT
        safety.watchdog(t)
    assert t - 1.0 <= 0.05
    assert t - 1.0 >= WATCHDOG_TRIP * 0.05 - DT
    assert "DYNO_FEEDBACK" in safety.reason


def test_a_host_that_wakes_a_watchdog_late_stops_the_run_as_its_own_stall():
    """Feedback stamped on arrival looks fresh after the host's own stall; the host's wake-up
    times tell: a loop that ran every cycle goes on, one that wakes 0.8 watchdogs late
    stops, naming the host."""
    p = SafetyParams()
    safety = SafetyLayer(p, DT)
    for k in range(100):
        safety.host_wakes(k * 1.5 * DT)            # a cycle without feedback each 1.5 ms
    assert safety.enable
    safety.host_wakes(99 * 1.5 * DT + WATCHDOG_TRIP * p.watchdog_s)
    assert not safety.enable and safety.reason.startswith("the host stalled")


@pytest.mark.parametrize(("stroke", "force", "what"), [(0.07, 0.0, "stroke"),
                                                  (0.0, 9000.0, "force")])
def test_measured_limits_stop_the_run(stroke, force, what):
    safety = SafetyLayer(SafetyParams(stroke_limit_m=0.06, force_limit_n=8000.0), DT)
    safety.feedback(0.0, 0.0, 0.0)
    safety.feedback(0.001, stroke * 1e-3, 0.0)
    assert safety.enable
    safety.feedback(0.010, stroke, force)
    assert not safety.enable and what in safety.reason


def test_measured_velocity_limit_stops_the_run():
    safety = SafetyLayer(SafetyParams(velocity_limit_m_s=1.0), DT)
    for k in range(20):                        # 2 m/s
        safety.feedback(k * DT, 2.0 * k * DT, 0.0)
    assert not safety.enable and "velocity" in safety.reason


def test_instability_detector_stops_growth_but_not_a_bounded_error():
    rng = np.random.default_rng(0)
    ref = 0.01 * np.sin(2 * np.pi * 1.3 * np.arange(5000) * DT)
    bounded = SafetyLayer(SafetyParams(), DT)
    for k in range(5000):                      # 3 x the reference, noisy, not growing
        bounded.tracking(k * DT, 0.03 * rng.standard_normal(), ref[k])
    assert bounded.enable
    growing = SafetyLayer(SafetyParams(), DT)
    k = 0
    while growing.enable and k < 5000:         # e-folding in 0.1 s, from 0.1 mm
        growing.tracking(k * DT, 1e-4 * math.exp(k * DT / 0.1)
                         * math.sin(2 * np.pi * 9 * k * DT), ref[k])
        k += 1
    assert not growing.enable and "unstable" in growing.reason
    assert k * DT < 1.0


# -- the loop, offline -------------------------------------------------------------------

def _run(model, *, mode="model", delay_s=0.004, duration_s=4.0, specimen=None,
         disturbance=None, safety=None, max_time_s=60.0):
    host = HybridHost(HybridRunParams(duration_s=duration_s), load_quarter_car(), model,
                      CompensatorParams(mode=mode), safety or SafetyParams())
    rig = VirtualRig(specimen or model, ActuatorParams(delay_s=delay_s), RigParams())
    run_offline(host, rig, disturbance=disturbance or Disturbance(), max_time_s=max_time_s)
    return host, rig


def _late_ride(model, out, every=7, late_cycles=5):
    """A short ride whose every ``every``-th feedback comes ``late_cycles`` cycles late,
    recorded with a hand-over after each cycle (the most a recorder's thread can do)."""
    from ride_sim.hybrid.recorder import HybridRecorder

    host = HybridHost(HybridRunParams(duration_s=0.5), load_quarter_car(), model,
                      CompensatorParams(), SafetyParams())
    rig = VirtualRig(model, ActuatorParams(delay_s=0.004), RigParams())
    out.mkdir()
    with HybridRecorder(out, host, bag=False, in_process=True, period_s=3600.0) as rec:
        run_offline(host, rig, disturbance=Disturbance(late_every=every,
                                                       late_cycles=late_cycles),
                    after_cycle=rec.hand_over, max_time_s=30.0)
    written = np.loadtxt(out / "hybrid.csv", delimiter=",", skiprows=1)
    return host, written


def test_a_late_feedback_is_in_the_record_the_recorder_wrote_while_the_run_went_on(
        model, tmp_path, monkeypatch):
    """Every 7th feedback comes 5 cycles late: its cycle runs on the last measurement, and
    the host puts the measurement in that sample's place when it comes.  The recorder
    hands over after every cycle, all but the newest ``LATE_CYCLES`` samples: hybrid.csv
    holds every late measurement in its place, as the host's record does.  Handing over
    every sample at once (no hold-back) writes the late ones before they come: the same
    check finds them."""
    import ride_sim.hybrid.recorder as recorder

    host, written = _late_ride(model, tmp_path / "held")
    assert host.phase == "done", host.reason
    n = host.k
    assert host.placed_late >= n // 7 - 2     # (those in the run proper, all placed)
    measured = written[:, 4:6].T              # stroke_measured, force_measured
    assert written.shape[0] == n
    np.testing.assert_allclose(measured, host.record[2:4, :n], rtol=1e-8, atol=1e-12)

    monkeypatch.setattr(recorder, "LATE_CYCLES", 0)
    host, written = _late_ride(model, tmp_path / "not_held")
    stale = ~np.isclose(written[:, 4:6].T, host.record[2:4, :host.k], rtol=1e-8,
                        atol=1e-12).all(axis=0)
    assert stale.sum() == host.placed_late > 0


def test_a_ride_shorter_than_its_ramps_goes_on_with_the_periodic_road():
    """The ramp out continues the evaluated road (one period of the periodic road) with its
    start, also when the ride is shorter than the ramp."""
    from ride_sim.hybrid.host import hybrid_road

    run = HybridRunParams(duration_s=0.5, ramp_s=1.0)
    road = hybrid_road(run, DT)
    h, lead, n = road.heights, road.n_lead, road.n_eval
    assert lead == 1000 and n < lead and h.size == 3 * lead + n
    ramp_out = h[lead + n: 2 * lead + n]
    weight = 0.5 + 0.5 * np.cos(np.pi * np.arange(1, lead + 1) / lead)   # 1 → 0
    np.testing.assert_allclose(ramp_out, np.resize(h[lead: lead + n], lead) * weight,
                               rtol=1e-12, atol=1e-15)
    assert not h[2 * lead + n:].any()


def _nrms(host, sl):
    xt, xm = host.record[0, sl], host.record[2, sl]
    return float(np.sqrt(np.mean((xm - xt) ** 2) / np.mean(xt ** 2)))


@pytest.fixture(scope="module")
def compensated(model):
    return _run(model)[0]


@pytest.fixture(scope="module")
def uncompensated(model):
    return _run(model, mode="none")[0]


def test_compensated_loop_tracks_and_rides_as_the_reference(compensated):
    host = compensated
    assert host.phase == "done" and host.reason is None
    assert _nrms(host, host.road.evaluated) < 0.02
    ride = host.ride_metrics()
    for key in RIDE_KEYS:
        assert ride[key] == pytest.approx(host.reference_metrics[key], rel=0.03)
    assert host.transfer.delay_s == pytest.approx(0.005, abs=0.2e-3)


def test_uncompensated_loop_lags_and_rides_differently(uncompensated, compensated):
    host = uncompensated
    assert host.phase == "done"
    assert _nrms(host, host.road.evaluated) > 5 * _nrms(compensated, host.road.evaluated)
    ride = host.ride_metrics()
    # the lag takes the damper's damping at the wheel hop: the car moves more
    assert ride["dtl_rms"] > 1.1 * host.reference_metrics["dtl_rms"]


def test_adaptation_follows_a_doubled_delay(model):
    host, _ = _run(model, duration_s=6.0,
                   disturbance=Disturbance(delay_change_at_s=6.0, new_delay_s=0.008))
    assert host.phase == "done"
    # the ride starts after connect, settle, identification and fit: find the change
    # the ride starts 3.5 s into the run (settle, identification): the delay changes 2.5 s
    # into the ride, after the tracker's first updates (1 s of data each)
    before = float(np.median(host.delay_estimate_s[1200:2400]))
    change = int(np.argmax(host.delay_estimate_s > before + 0.002))
    assert change > 0
    after = slice(change + 1500, change + 2000)       # within 2 s of the change
    assert _nrms(host, after) < 0.05
    # the tracker has found the 4 ms more
    assert host.tracker.delay_s - before == pytest.approx(0.004, abs=0.3e-3)


def test_feedback_cut_clears_enable_within_the_watchdog(model):
    host, _rig = _run(model, disturbance=Disturbance(feedback_cut_at_s=5.0))
    assert host.phase == "stopped" and "DYNO_FEEDBACK" in host.reason
    assert host.safety.stopped_at_s - host.safety.last_valid_s <= 0.05


def test_a_lost_frame_every_hundred_does_not_stop_the_run(model):
    from ride_sim.hybrid.criteria import summary

    host, _ = _run(model, disturbance=Disturbance(drop_every=100))
    assert host.phase == "done" and _nrms(host, host.road.evaluated) < 0.02
    # each lost frame's cycle holds the last measurement, and is counted as such
    tracked = summary(host)["tracking"]
    assert tracked["samples_without_measurement"] == pytest.approx(
        tracked["samples"] / 100, abs=1)


def test_unstable_setting_is_stopped_before_any_limit(model):
    safety = SafetyParams()
    host, _rig = _run(model, mode="none", delay_s=0.030, safety=safety)
    assert host.phase == "stopped" and "unstable" in host.reason
    measured = host.record[2, :host.k]
    force = host.record[3, :host.k]
    assert np.max(np.abs(measured)) < safety.stroke_limit_m
    assert np.max(np.abs(force)) < safety.force_limit_n
    assert np.max(np.abs(host.record[1, :host.k])) <= safety.stroke_limit_m


def test_a_thermal_fade_grows_the_twins_residual_and_the_online_twin_follows_it(model):
    """A specimen whose oil thins as it warms (the viscosity–temperature extension, a form
    the online map does not have): the twin as it came to the ride drifts away from it,
    and the online correction, learning from the ride itself, keeps its prediction close
    (each force a prediction made before its own sample taught the map)."""
    cfg = load_config()
    fading = DamperModel(with_extensions(cfg, {"viscosity_temperature": dict(
        temperature_coefficient_per_k=0.03, reference_temperature_c=25.0,
        heat_capacity_j_per_k=200.0, cooling_time_constant_s=600.0)}))
    host, rig = _run(model, specimen=fading, duration_s=10.0)
    assert rig.specimen.temperature_rise_k > 3.0
    sl = host.road.evaluated

    def first_last(predicted):
        residual = host.record[3] - predicted
        return (np.sqrt(np.nanmean(residual[sl.start: sl.start + 2000] ** 2)),
                np.sqrt(np.nanmean(residual[sl.stop - 2000: sl.stop] ** 2)))

    raw_first, raw_last = first_last(host.twin_raw)
    _, online_last = first_last(host.record[4])
    assert raw_last > 2.0 * raw_first
    assert online_last < 0.5 * raw_last
    assert host.online.updates > 0.9 * (sl.stop - sl.start)
    # the oil thinned: the valves' force the map learned is below the twin's
    terms = host.online.terms()
    assert terms["compression_gain"] < 1.0 and terms["rebound_gain"] < 1.0


def test_force_path_gain_is_below_one_by_default_and_the_hazard_above():
    car = load_quarter_car()
    est = TransferEstimate(0.005, 40.0, 0.7, 1.0)
    default, _ = force_path_gain(CompensatorParams(), est, car, 20e3, DT)
    assert 0.0 < default < 1.0
    # without the correction's band limit and with a steeper damper, the measured force
    # reaches the demand with a loop gain above one: the naive compensator's limit cycle
    hazard, f = force_path_gain(CompensatorParams(force_correction_hz=500.0), est, car,
                                80e3, DT)
    assert hazard > 1.0 and f > 20.0
    assert force_path_gain(CompensatorParams(mode="none"), est, car, 20e3, DT)[0] == 0.0


def test_parameter_groups_refuse_bad_values_in_one_line():
    with pytest.raises(Exception, match=r"safety\.watchdog_s"):
        build(SafetyParams, {"watchdog_s": 0.0}, "safety")
    with pytest.raises(Exception, match=r"actuator\.bandwidth_hz"):
        build(ActuatorParams, {"bandwidth_hz": -1.0}, "actuator")


# -- stalls of the host during the identification ------------------------------------------

def _stalled_run(model, stalls, compensator=None, run=None, cut_at_s=None, backlog=None):
    """A short ride whose host stalls over ``stalls`` ((start, length) [s]): the
    identification runs from about 0.5 s to 3.5 s into the run."""
    host = HybridHost(run or HybridRunParams(duration_s=0.5), load_quarter_car(), model,
                      compensator or CompensatorParams(), SafetyParams())
    rig = VirtualRig(model, ActuatorParams(delay_s=0.004), RigParams())
    run_offline(host, rig, disturbance=Disturbance(host_stalls=stalls,
                                                   feedback_cut_at_s=cut_at_s,
                                                   backlog_frames=backlog),
                max_time_s=30.0)
    return host


@pytest.fixture(scope="module")
def three_stalls(model):
    return _stalled_run(model, tuple((t, 0.015) for t in (1.0, 1.7, 2.4)))


def test_the_cycles_a_stall_disturbed_are_left_out_of_the_identification(three_stalls):
    """Three 15 ms stalls of the host in the identification (the rig holds its last demand,
    then gets the backlog's commands at once): each leaves out its cycles and the guard
    after them, and the fit finds the clean run's transfer system."""
    host = three_stalls
    assert host.phase == "done" and host.reason is None
    (attempt,) = host.attempts
    # of each stall's 15 cycles, the 12 whose commands go out more than 3 cycles late (their
    # feedbacks came 0.25 ms after the rig's cycle, the commands at the stall's end)
    assert attempt["stalls"] == 3 and attempt["disturbed_cycles"] == 3 * 12
    guard = round(CompensatorParams().stall_guard_s / DT)
    assert attempt["left_out"] == pytest.approx(3 * (12 + guard) / host.usable.size, abs=1e-9)
    assert host.transfer.delay_s == pytest.approx(0.005, abs=0.2e-3)
    assert host.transfer.bandwidth_hz == pytest.approx(ActuatorParams().bandwidth_hz, rel=0.05)
    assert attempt["fit_nrms"] < 0.05


def test_the_stalls_left_in_would_spoil_the_identification(three_stalls):
    u, x = three_stalls.identification
    kept = identify(u, x, DT, usable=three_stalls.usable)
    spoiled = identify(u, x, DT)
    assert spoiled.fit_nrms > 3 * kept.fit_nrms


def test_an_identification_that_stalls_throughout_runs_again(model):
    """Stalls every 30 ms over the first identification leave out most of it: it runs
    again, without a fit, and the second, clean, is the ride's."""
    host = _stalled_run(model, tuple((0.6 + 0.03 * i, 0.01) for i in range(80)))
    first, second = host.attempts
    assert first["fit_nrms"] is None and first["left_out"] > 0.5
    assert second["stalls"] == 0 and second["fit_nrms"] < 0.05
    assert host.phase == "done" and host.reason is None


def test_an_identification_that_never_gets_clear_of_stalls_stops_the_run(model):
    host = _stalled_run(model, tuple((0.6 + 0.03 * i, 0.01) for i in range(240)),
                        CompensatorParams(identify_attempts=2))
    assert host.phase == "stopped" and host.transfer is None
    assert [a["fit_nrms"] for a in host.attempts] == [None, None]
    assert "stalls" in host.reason and "attempt 2 of 2" in host.reason
    assert not host.safety.enable


def test_a_timing_stop_before_the_ride_starts_the_run_again(model):
    """A 200 ms stall of the host in the identification stops the run (the host's own
    watchdog); before the ride nothing is lost but time, so the host clears Enable for the
    watchdog's time, connects again and starts over: the ride completes, the restart in
    ``identification``.  With ``restarts: 0`` the stop is final."""
    host = _stalled_run(model, ((1.0, 0.2),))
    assert host.phase == "done" and host.reason is None, host.reason
    (restart,) = host.identification_report()["restarts"]
    assert restart["phase"] == "identify" and "the host stalled" in restart["reason"]
    assert 0.99 < restart["at_s"] < 1.3
    # the identification that ran was the second, clean one
    (attempt,) = host.attempts
    assert attempt["stalls"] == 0 and attempt["fit_nrms"] < 0.1
    assert _nrms(host, host.road.evaluated) < 0.05

    final = _stalled_run(model, ((1.0, 0.2),), run=HybridRunParams(duration_s=0.5,
                                                                    restarts=0))
    assert final.phase == "stopped" and "the host stalled" in final.reason
    assert final.identification_report()["restarts"] == [] and final.k == 0


def test_a_stall_whose_backlog_overflowed_restarts_once(model):
    """A 200 ms stall whose socket kept only the first 150 ms of feedback (the newest
    dropped): the frames that waited are stale, and their gap before the frames after the
    stall is not the rig's silence.  One restart, and the ride completes (the gap once
    tripped the new watchdog in ``rearm`` and spent every restart)."""
    host = _stalled_run(model, ((1.0, 0.2),), backlog=150)
    assert host.phase == "done", host.reason
    (restart,) = host.identification_report()["restarts"]
    assert "the host stalled" in restart["reason"]


def test_stale_feedback_is_left_out_on_every_path_after_a_restart(model):
    """The link hands a restart's stale frames (stamped before it) to the host as late
    feedback, or as the newest measurement when its counter cannot place them, not only
    through a cycle: none of them feeds the new watchdog, so a read that times out after
    them does not stop the run again (it once spent the second restart in ``rearm``)."""
    host = HybridHost(HybridRunParams(duration_s=0.5), load_quarter_car(), model,
                      CompensatorParams(), SafetyParams())
    dt = host.dt_s
    feedback = Feedback(0.0, -400.0, 0, 25.0)
    for k in range(50):                                 # connect, then settle
        host.safety.host_wakes(k * dt)
        host.cycle(k * dt, feedback, now_s=k * dt)
    assert host.phase == "settle"
    held_until = 0.3                                    # the host held for 250 ms
    host.safety.host_wakes(held_until)
    host.cycle(0.05, feedback, now_s=held_until)        # the first frame that waited
    assert host.phase == "rearm" and len(host.restarts) == 1
    host.late(0.10, feedback, 0)                        # the link's late path
    host.measure(0.11, feedback)                        # its path past the counter
    assert host.safety.last_valid_s is None
    host.cycle(held_until + 2 * dt, None, now_s=held_until + 2 * dt)   # a read timed out
    assert host.safety.enable and len(host.restarts) == 1


def test_a_gap_in_the_feedback_while_rearming_is_no_second_stop(model):
    """In ``rearm`` Enable is clear and the host waits out the rig's watchdog: a fresh
    frame there, then none for the watchdog's trip, is no stop (it once spent the second
    restart in ``rearm`` on a loaded machine), nor is the wait for the rig in ``connect``
    after it; the first frame there starts the new watchdog's clock and the start
    goes on."""
    host = HybridHost(HybridRunParams(duration_s=0.5), load_quarter_car(), model,
                      CompensatorParams(), SafetyParams())
    dt = host.dt_s
    watchdog_s = SafetyParams().watchdog_s
    feedback = Feedback(0.0, -400.0, 0, 25.0)
    for k in range(50):                                 # connect, then settle
        host.safety.host_wakes(k * dt)
        host.cycle(k * dt, feedback, now_s=k * dt)
    held_until = 0.3                                    # the host held for 250 ms
    host.safety.host_wakes(held_until)
    host.cycle(0.05, feedback, now_s=held_until)
    assert host.phase == "rearm" and len(host.restarts) == 1
    t = held_until + dt
    host.safety.host_wakes(t)
    host.cycle(t, feedback, now_s=t)                    # a fresh frame while rearming
    assert host.safety.last_valid_s == t
    while host.phase == "rearm":                        # then none: the rig's watchdog
        t += dt
        host.safety.host_wakes(t)
        host.cycle(t, None, now_s=t)
    assert host.phase == "connect" and host.safety.enable and len(host.restarts) == 1
    assert t - held_until >= watchdog_s
    for _ in range(round(2 * watchdog_s / dt)):         # no rig yet, for two watchdogs
        t += dt
        host.safety.host_wakes(t)
        host.cycle(t, None, now_s=t)
    assert host.phase == "connect" and host.safety.enable
    t += dt
    host.safety.host_wakes(t)
    host.cycle(t, feedback, now_s=t)                    # the rig is back
    assert host.phase == "settle" and host.safety.last_valid_s == t
    assert len(host.restarts) == 1


def test_each_restart_is_timed_from_the_runs_start(model):
    """Two stalls, each in an identification: two restarts, each stamped with its time
    into the run (not into the start before it), and the ride completes."""
    host = _stalled_run(model, ((1.0, 0.2), (2.6, 0.2)))
    assert host.phase == "done", host.reason
    first, second = host.identification_report()["restarts"]
    assert 0.99 < first["at_s"] < 1.3 and 2.59 < second["at_s"] < 2.9


def test_a_feedback_cut_before_the_ride_stops_once_the_restart_finds_no_rig(model):
    """The feedback cut in the identification: the restart waits ``connect_timeout_s`` for
    the rig, then the watchdog's stop stands (a stop, not a failure to connect)."""
    host = _stalled_run(model, (), run=HybridRunParams(duration_s=0.5, connect_timeout_s=0.5),
                        cut_at_s=1.5)
    assert host.phase == "stopped" and host.safety.timing
    assert host.reason.startswith("no valid DYNO_FEEDBACK") and "of the restart" in \
        host.reason, host.reason
    assert host.failure is None and len(host.restarts) == 1


def test_a_stall_in_the_ride_is_reported_and_left_out_of_the_tracking_outside_stalls(
        model, compensated):
    """A 15 ms stall of the host 1.5 s into the evaluated ride: 12 of its cycles run more
    than 3 cycles late.  Those whose feedback came within a transport delay of the
    backlog's first are samples (the rig still moved), the others are held, and the sample
    after the hold is marked: the report counts them, the tracking over the whole ride
    shows the stall, and outside its window it is better, but not the clean run's."""
    from ride_sim.hybrid.criteria import summary

    at = (compensated.road.n_lead + 1500) * DT + 3.6      # the ride starts ≈ 3.6 s in
    host, _ = _run(model, disturbance=Disturbance(host_stalls=((at, 0.015),)))
    assert host.phase == "done"
    doc = summary(host)
    stalls = doc["stalls"]
    late = 12
    delay_cycles = int(np.ceil(host.tracker.delay_s / DT))
    assert stalls["held_cycles"] == late - delay_cycles
    assert stalls["count"] == 1 and stalls["samples"] == late - stalls["held_cycles"] + 1
    assert stalls["longest_ms"] == pytest.approx(14.75, abs=0.01)
    guard = round(CompensatorParams().stall_guard_s / DT)
    tracked = doc["tracking"]
    assert tracked["samples_in_stalls"] == stalls["samples"] + guard
    clean = summary(compensated)["tracking"]
    assert clean["samples_in_stalls"] == 0 and clean["nrms"] == clean["nrms_outside_stalls"]
    assert clean["nrms"] < tracked["nrms_outside_stalls"] < tracked["nrms"]


@pytest.mark.parametrize("stall_s", [0.03, 0.038])
def test_after_a_long_stall_the_car_resumes_where_the_rig_stood(model, compensated,
                                                                stall_s):
    """A stall of the host shorter than the watchdog, where the damper moves fast: the
    rig runs through the demands it had and stands; the car holds with it instead of
    running ahead on the backlog.  Its target does not jump (no step beyond a cycle's
    motion around the stall), and the tracking error after the stall is
    a servo starting from rest, bounded by the speed times the rig's delay plus the
    servo's time constant 2ζ/ω (independent of the stall's length; running the backlog as
    samples left 7.7 and 9.4 mm at 30 and 45 ms here, against bounds of about 3.7 mm;
    from 40 ms the host's own watchdog stops the run)."""
    at = (compensated.road.n_lead + 1500) * DT + 4.3
    host, _ = _run(model, disturbance=Disturbance(host_stalls=((at, stall_s),)))
    assert host.phase == "done" and host.reason is None
    k = int(np.argmax(host.stalled[: host.k]))
    assert host.held_cycles >= round(stall_s / DT) - 10
    target, measured = host.record[0, : host.k], host.record[2, : host.k]
    speed = np.abs(np.gradient(target, DT))
    after = slice(k, k + 150)
    near = slice(k - 5, k + 20)
    assert np.max(np.abs(np.diff(target[near]))) <= 1.5 * speed[near].max() * DT
    rig = ActuatorParams(delay_s=0.004)
    servo_s = 2.0 * rig.damping / (2.0 * np.pi * rig.bandwidth_hz)
    bound = speed[after].max() * (rig.delay_s + servo_s)
    assert np.max(np.abs(measured[after] - target[after])) <= bound


def test_measured_velocity_counts_the_cycles_of_lost_frames():
    safety = SafetyLayer(SafetyParams(velocity_limit_m_s=1.5), DT)
    cycle = 0
    for k in range(30):                       # 1.2 m/s, every third frame lost
        cycle += 2 if k % 3 == 2 else 1
        safety.feedback(k * DT, 1.2 * cycle * DT, 0.0, cycle)
    assert safety.enable
    assert safety.velocity_m_s == pytest.approx(1.2, rel=1e-9)


# -- the twin learns the specimen --------------------------------------------------------


@pytest.mark.slow
def test_the_twin_learns_a_specimen_that_is_not_its_model(model, tmp_path):
    """The characterisation (a quasi-static test and a chirp) on the sport prototype
    (``config/prototype.yaml``: other valves, a stiffer oil, a LuGre friction, a thermal
    fade), through a load cell with 2 N of noise, identified into the sport twin:
    on the damper strokes of a class-C ride (motion it never learned from) the sport twin
    misses the specimen's force by 30 % r.m.s. or more, the learned one by 10 % at most;
    the learned parameter file reads back as the same model."""
    from types import SimpleNamespace

    from damper_emulator.model.compressible import simulate
    from damper_emulator.params import PROTOTYPE_FILE
    from ride_sim.hybrid.host import hybrid_road, reference_run
    from ride_sim.hybrid.learn import learn_twin
    from ride_sim.hybrid.params import LearnParams

    specimen = DamperModel(load_config(PROTOTYPE_FILE))
    rng = np.random.default_rng(3)

    def rig(_twin, t, x, v):
        res = simulate(specimen, t, x, v)
        return SimpleNamespace(force_n=res.force_n + rng.normal(0.0, 2.0, t.size),
                               faults=res.faults)

    learned = learn_twin(model, LearnParams(), tmp_path, rig)
    for name in ("quasi_static.csv", "chirp.csv"):
        assert learned.after[name]["rms_n"] < learned.before[name]["rms_n"]
    road = hybrid_road(HybridRunParams(duration_s=10.0), DT)
    x = reference_run(load_quarter_car(), model, road, DT)[0].damper_stroke_m
    t = np.arange(x.size) * DT
    v = np.gradient(x, t)
    truth = simulate(specimen, t, x, v).force_n

    def miss(m):
        return np.sqrt(np.mean((simulate(m, t, x, v).force_n - truth) ** 2)
                       / np.mean(truth ** 2))

    assert miss(model) >= 0.3
    assert miss(learned.model) <= 0.1
    again = DamperModel(load_config(learned.params_file))
    np.testing.assert_allclose(simulate(again, t, x, v).force_n,
                               simulate(learned.model, t, x, v).force_n, rtol=1e-9, atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize(("safety", "stall", "calls"), [
    (SafetyParams(), True, 3),                          # run again: QS twice, the chirp
    (SafetyParams(force_limit_n=100.0), False, 1),      # a limit: no second run
])
def test_a_test_a_stall_stopped_runs_again_and_one_a_limit_stopped_does_not(
        model, tmp_path, safety, stall, calls):
    """The characterisation's quasi-static test, on a host and rig of the run (offline
    timeline): a 200 ms stall of the host in the test proper stops it by the host's own
    watchdog (before it, the host starts again by itself), and it runs again (then the
    learning goes on); a force beyond the limit stops it for the specimen, and the
    learning stops with it."""
    from damper_emulator.model.compressible import simulate
    from ride_sim.hybrid.learn import learn_twin
    from ride_sim.hybrid.params import LearnParams
    from ride_sim.hybrid.protocol_host import ProtocolHost
    from ride_sim.hybrid.safety import RunStopped

    seen: list[str] = []
    ran = []

    def engine(twin, t, x, v):
        ran.append(t.size)
        if len(ran) == 1:
            host = ProtocolHost(HybridRunParams(), CompensatorParams(), safety, x, DT)
            rig = VirtualRig(model, ActuatorParams(delay_s=0.004), RigParams())
            run_offline(host, rig, max_time_s=60.0, disturbance=Disturbance(
                host_stalls=((3.8, 0.2),) if stall else ()))
            assert host.phase == "stopped"
            raise RunStopped(host.reason, timing=host.safety.timing)
        res = simulate(model, t, x, v)
        return SimpleNamespace(force_n=res.force_n, faults=res.faults)

    from types import SimpleNamespace

    if stall:
        learned = learn_twin(model, LearnParams(), tmp_path, engine, progress=seen.append)
        assert learned.params_file.exists()
        assert any("the quasi_static test stopped (the host stalled" in line
                   and "run 2 of at most 3" in line for line in seen), seen
    else:
        with pytest.raises(RunStopped, match="beyond the limit"):
            learn_twin(model, LearnParams(), tmp_path, engine, progress=seen.append)
    assert len(ran) == calls


@pytest.mark.parametrize(("change", "says"), [
    ({"chirp_end_velocity_m_s": 2.0}, "velocity_limit_m_s"),
    ({"quasi_static_amplitude_m": 0.08}, "stroke_limit_m"),
])
def test_a_characterisation_beyond_the_safety_limits_is_refused(change, says):
    import dataclasses

    from damper_emulator.errors import UserError
    from ride_sim.hybrid.learn import check_safe
    from ride_sim.hybrid.params import LearnParams

    with pytest.raises(UserError, match=says):
        check_safe(dataclasses.replace(LearnParams(), **change), SafetyParams())
