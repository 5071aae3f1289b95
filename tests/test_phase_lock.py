"""The timer loop's phase lock to its input (damper_emulator.realtime.phase_lock), against
the closed forms of a first-order loop, in simulated time; and the loop's deadline shift
on a real thread."""

from __future__ import annotations

import time

import numpy as np
import pytest

from damper_emulator.realtime.loop import PeriodicLoop
from damper_emulator.realtime.phase_lock import GAIN, MAX_STEP_FRACTION, PhaseLock, wrap
from damper_emulator.realtime.settings import default_emulator_mapping, emulator_params_from_mapping
from damper_emulator.schema import ParameterError

US = 1_000
P = 1_000 * US              # the loop's period: 1 kHz
TARGET = 200 * US


def run(lock: PhaseLock, input_period_ns: int, first_arrival_ns: int, ticks: int,
        first_tick_ns: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulated time: a loop ticking at ``P`` plus the lock's shifts, inputs arriving every
    ``input_period_ns``.  Returns the tick times, each tick's inputs taken and its lag
    after the newest one's arrival (−1: none)."""
    t = first_tick_ns
    arrival = first_arrival_ns
    last = t - P
    times, counts, lags = [], [], []
    for _ in range(ticks):
        newest, count = -1, 0
        while arrival <= t:
            if arrival > last:
                newest, count = arrival, count + 1
            arrival += input_period_ns
        lag = t - newest if count else -1
        times.append(t)
        counts.append(count)
        lags.append(lag)
        last = t
        t += P + lock.shift_ns(count, lag)         # every tick, as the emulator calls it
    return np.array(times), np.array(counts), np.array(lags)


def test_wrap_is_the_nearest_equivalent_error():
    for e in range(-3 * P, 3 * P, 37_123):
        w = wrap(e, P)
        assert -P // 2 <= w < P // 2 and (e - w) % P == 0


def test_a_small_error_decays_as_one_minus_gain_to_the_n():
    # 50 µs late: below the step's cap, so each tick takes GAIN of the error off
    lock = PhaseLock(P, TARGET)
    _times, counts, lags = run(lock, P, first_arrival_ns=-(TARGET + 50 * US), ticks=40)
    assert (counts == 1).all()
    n = np.arange(40)
    # the first tick with an input has none before it: the corrections start at the second
    expected = 50 * US * (1 - GAIN) ** np.maximum(n - 1, 0)
    # each shift is rounded to a whole ns: at most n ns apart after n ticks
    assert np.abs((lags - TARGET) - expected).max() <= n.max() + 1


def test_from_the_worst_phase_the_ticks_move_later_and_settle_on_the_target():
    # a tick 1 µs before each arrival: every input waits almost a whole period
    lock = PhaseLock(P, TARGET)
    times, _counts, lags = run(lock, P, first_arrival_ns=1 * US, ticks=300)
    steps = np.diff(times) - P
    assert steps.max() <= MAX_STEP_FRACTION * P and steps.min() >= -MAX_STEP_FRACTION * P
    assert lags[1] > P - 2 * US                      # the first input waited a period
    # later ticks, never earlier ones, while the error is one sign
    first_settled = int(np.argmax(np.abs(lags - TARGET) < 1 * US))
    assert first_settled > 0 and (steps[:first_settled - 1] >= 0).all()
    assert np.abs(lags[-50:] - TARGET).max() < 1 * US


@pytest.mark.parametrize("fast", [0.01, -0.01])
def test_an_input_clock_off_by_one_percent_is_followed_with_the_closed_form_lag(fast):
    lock = PhaseLock(P, TARGET)
    input_period = round(P * (1 - fast))
    times, _counts, lags = run(lock, input_period, first_arrival_ns=-TARGET, ticks=2000)
    # the loop takes the input's period; the error settles where the correction per tick
    # equals the drift per tick: GAIN · e = P − P_in
    assert np.mean(np.diff(times[-500:])) == pytest.approx(input_period, abs=1)
    assert np.median(lags[-500:] - TARGET) == pytest.approx((P - input_period) / GAIN,
                                                            abs=2 * US)


@pytest.mark.parametrize("ratio", [3.0, 1.5, 0.3, 0.5])
def test_an_input_at_another_rate_leaves_the_loop_on_its_own(ratio):
    """Three, 1.5, 0.3 or half the loop's rate: ticks take 3, 1-2-1-2, mostly none, or
    every other one input; no tick with one input follows another, so nothing moves (a
    lock on the odd single inputs ran a 1 kHz loop at 1010 Hz under a 1.5 kHz input)."""
    times, counts, _ = run(PhaseLock(P, TARGET), round(P / ratio), first_arrival_ns=1,
                           ticks=200)
    assert (np.diff(times) == P).all(), np.unique(counts)


def test_ticks_with_no_input_or_several_leave_the_phase_alone():
    lock = PhaseLock(P, TARGET)
    assert lock.shift_ns(0, 0) == 0 and lock.shift_ns(3, 900 * US) == 0
    assert lock.shift_ns(1, 400 * US) == 0          # one input, after a tick with three
    assert lock.shift_ns(1, 400 * US) < 0           # and again: the ticks move earlier
    with pytest.raises(ValueError, match="target lag"):
        PhaseLock(P, P)


def test_phase_lock_parameter_must_be_shorter_than_the_period():
    data = default_emulator_mapping()
    with pytest.raises(ParameterError, match="phase_lock_us = 500 must be shorter") as err:
        emulator_params_from_mapping({**data, "rate_hz": 2000.0, "phase_lock_us": 500.0})
    assert "\n" not in str(err.value)
    # off, or under the input trigger (no loop), any rate goes
    emulator_params_from_mapping({**data, "rate_hz": 20000.0, "phase_lock_us": 0.0})
    emulator_params_from_mapping({**data, "rate_hz": 20000.0, "trigger": "input"})


def test_a_shift_moves_the_next_deadline_and_every_later_one():
    period = 2_000_000
    ticks: list[int] = []
    loop: PeriodicLoop

    def tick(now: int) -> None:
        ticks.append(now)
        if len(ticks) == 5:
            loop.shift_next(period // 2)

    loop = PeriodicLoop(period * 1e-9, tick, capacity=100)
    loop.start()
    time.sleep(0.05)
    loop.stop()
    assert loop.error is None and len(ticks) > 8
    t = np.array(ticks)
    # the deadlines (each tick's wake-up less its lateness, as the loop records them): one
    # period apart (or whole periods, where a busy machine made the loop skip), the one
    # after the shift half a period more, and never after their tick
    wake = loop.stats.wake_ns()
    assert wake.size == t.size and (wake >= 0).all()
    steps = np.diff(t - wake) - np.where(np.arange(t.size - 1) == 4, period // 2, 0)
    assert (steps % period == 0).all() and (steps > 0).all()
    assert (steps // period - 1).sum() == loop.stats.skipped
