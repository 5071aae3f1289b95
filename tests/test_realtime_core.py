"""The emulator's ROS-free core: input checks, hold / extrapolation, timeout and fault
outputs, and the fixed-rate loop's deadline statistics."""

import contextlib
import dataclasses
import math
import os
import struct
import threading
import time

import numpy as np
import pytest

from damper_emulator.model.compressible import DamperStepper
from damper_emulator.realtime import rt
from damper_emulator.realtime.core import EmulatorCore, Status
from damper_emulator.realtime.loop import LoopStats, PeriodicLoop, load_record
from damper_emulator.realtime.rt import RealtimeRequest, apply_realtime, normal_scheduling
from damper_emulator.realtime.settings import default_emulator_mapping, emulator_params_from_mapping
from damper_emulator.schema import ParameterError

MS = 1_000_000


@pytest.fixture(scope="module")
def params():
    return emulator_params_from_mapping(default_emulator_mapping(), "config/emulator.yaml")


def make(model, params, **changes):
    return EmulatorCore(model, dataclasses.replace(params, **changes))


def test_default_file_matches_dataclass_defaults(params):
    from damper_emulator.realtime.settings import EmulatorParams
    assert params == EmulatorParams()


def test_bad_parameters_are_one_line_errors(params):
    data = default_emulator_mapping()
    for key, value, words in (("rate_hz", -5.0, "rate_hz"), ("fault_mode", "brake", "one of"),
                              ("sched_fifo", "yes", "true or false"),
                              ("valve_command", 1.5, "[0, 1]")):
        with pytest.raises(ParameterError, match=words) as err:
            emulator_params_from_mapping({**data, key: value}, "f.yaml")
        assert "\n" not in str(err.value)
    with pytest.raises(ParameterError, match=r"unknown parameter emulator\.rate"):
        emulator_params_from_mapping({**data, "rate": 1.0}, "f.yaml")


def test_input_mode_follows_an_independent_stepper(sport_model, params):
    """trigger: input steps the model by the stamp differences: the same forces as a
    DamperStepper driven directly with those steps."""
    core = make(sport_model, params, trigger="input")
    ref = DamperStepper(sport_model)
    t = np.arange(200) * 0.7e-3
    x = 0.02 * np.sin(2 * np.pi * 3 * t)
    v = 0.02 * 2 * np.pi * 3 * np.cos(2 * np.pi * 3 * t)
    for k in range(t.size):
        out = core.evaluate(int(round(t[k] * 1e9)), x[k], v[k])
        if k == 0:
            ref.reset(x[0], v[0])
            expected = ref.force_n
        else:
            expected, _ = ref.step(x[k], v[k], (round(t[k] * 1e9) - round(t[k - 1] * 1e9)) * 1e-9)
        assert out.force_n == pytest.approx(expected, rel=1e-12, abs=1e-9)
        assert out.status == Status.OK


def test_non_finite_and_out_of_range_input_is_rejected_and_counted(sport_model, params):
    core = make(sport_model, params)
    now = 10 * MS
    assert core.submit(0, 0.01, 0.1, now) is None
    good = core.tick(now + MS)
    for x, v in ((math.nan, 0.1), (0.01, math.inf), (0.01, -math.nan)):
        assert "non-finite" in core.submit(0, x, v, now + MS)
    _lo, hi = sport_model.stroke_limits_m
    assert "outside the travel" in core.submit(0, hi + 0.05, 0.0, now + MS)
    assert "velocity" in core.submit(0, 0.0, 50.0, now + MS)
    assert core.counters.rejected_non_finite == 3 and core.counters.rejected_range == 2
    out = core.tick(now + 2 * MS)
    # the rejected samples were never used: the last good one is held
    assert out.stroke_m == 0.01 and out.velocity_m_s == 0.1
    assert math.isfinite(out.force_n) and out.status & Status.REJECTED
    assert abs(out.force_n - good.force_n) < 50.0
    # in input mode a NaN sample produces no output at all
    core = make(sport_model, params, trigger="input")
    assert core.evaluate(0, math.nan, 0.0) is None
    assert core.evaluate(MS, 0.0, 0.0) is not None
    assert core.evaluate(MS, 0.0, 0.0) is None          # stamp not increasing
    assert core.counters.rejected_stamp == 1


@pytest.mark.parametrize("mode", ["hold", "zero", "passive"])
def test_stale_input_gives_the_fault_output(sport_model, params, mode):
    core = make(sport_model, params, fault_mode=mode, input_timeout_s=0.02,
                passive_rate_ns_m=3000.0)
    out = core.tick(0)
    assert out.status & Status.NO_INPUT
    t = 0
    for k in range(50):            # 50 ms of a 0.3 m/s rebound stroke
        t = (k + 1) * MS
        core.submit(t, 0.3 * k * 1e-3, 0.3, t)
        last = core.tick(t)
    assert last.status == Status.OK and last.force_n > core.static_force_n
    fresh = core.tick(t + 19 * MS)
    assert fresh.status == Status.OK
    stale = core.tick(t + 21 * MS)
    assert stale.status & Status.TIMEOUT and core.counters.timeouts == 1
    expected = {"hold": fresh.force_n, "zero": 0.0,
                "passive": core.static_force_n + 3000.0 * 0.3}[mode]
    assert stale.force_n == pytest.approx(expected, rel=1e-12)
    # recovery: a new sample ends the fault
    core.submit(t + 30 * MS, 0.015, 0.0, t + 30 * MS)
    assert core.tick(t + 31 * MS).status == Status.OK


def test_extrapolation_uses_the_velocity_and_is_capped(sport_model, params):
    core = make(sport_model, params, input_mode="extrapolate", max_extrapolation_s=0.004)
    core.submit(0, 0.01, 0.5, 0)
    assert core.tick(2 * MS).stroke_m == pytest.approx(0.01 + 0.5 * 0.002, rel=1e-12)
    assert core.tick(10 * MS).stroke_m == pytest.approx(0.01 + 0.5 * 0.004, rel=1e-12)
    held = make(sport_model, params, input_mode="hold")
    held.submit(0, 0.01, 0.5, 0)
    assert held.tick(2 * MS).stroke_m == 0.01


def test_valve_command_range(sport_model, params):
    core = make(sport_model, params)
    assert core.set_valve_command(0.25) is None and core.valve_command == 0.25
    assert core.set_valve_command(1.5) is not None and core.valve_command == 0.25
    assert core.set_valve_command(math.nan) is not None


def test_loop_stats_percentiles_and_overruns():
    s = LoopStats(period_ns=1000, capacity=8)
    for p in (1000, 1000, 2500, 1000, 900, 1100, 1000, 1000, 1000, 3000):
        s.record(p)
    assert s.overruns == 2                       # 2500 and 3000 > 2 periods
    p = s.periods_ns()
    assert p.tolist() == [2500, 1000, 900, 1100, 1000, 1000, 1000, 3000]  # latest 8, in order
    summary = s.summary()
    assert summary.period_max_us == 3.0
    assert summary.achieved_rate_hz == pytest.approx(1e9 / np.mean(p))


def test_loop_stats_wake_and_work_rings_and_saved_record(tmp_path):
    s = LoopStats(period_ns=1000, capacity=4)
    for k in range(6):
        s.record_tick(wake_ns=10 * k, work_ns=100 * k)
    assert s.ticks == 6
    assert s.wake_ns().tolist() == [20, 30, 40, 50]         # latest 4, in order
    assert s.work_ns(last=2).tolist() == [400, 500]
    for p in (1000, 1200, 800):
        s.record(p)
    s.save(tmp_path / "loop.npz", realtime="none")
    data, summary = load_record(tmp_path / "loop.npz")
    assert str(data["realtime"]) == "none" and data["periods_ns"].tolist() == [1000, 1200, 800]
    assert summary.wake_p50_us == pytest.approx(np.percentile([20, 30, 40, 50], 50) / 1e3)
    assert summary.work_max_us == pytest.approx(0.5)
    assert summary.error_p99_us == pytest.approx(np.percentile([0, 200, 200], 99) / 1e3)


def test_periodic_loop_keeps_its_rate_and_counts_skips():
    ticks = []
    loop = PeriodicLoop(2e-3, lambda now: ticks.append(now), capacity=1000)
    started = time.monotonic()
    loop.start()
    time.sleep(0.3)
    loop.stop()
    wall_s = time.monotonic() - started     # the sleep may overrun on a busy machine
    assert loop.error is None
    n = len(ticks)
    # 500 Hz on absolute deadlines: never more ticks than deadlines in the time it ran
    # (one at its start), one at least, in order (how few a busy machine loses is a figure
    # of the host: benchmarks/node_bench.py measures the emulator loop's periods)
    assert 1 <= n <= wall_s / 2e-3 + 1
    assert (np.diff(ticks) > 0).all()
    # every tick's wake-up is at or after its deadline and is recorded with its work
    assert loop.stats.ticks == n and (loop.stats.wake_ns() >= 0).all()
    # a tick that takes 3 periods: the missed deadlines are skipped, not burst
    slow = PeriodicLoop(2e-3, lambda now: time.sleep(6.5e-3), capacity=100)
    slow.start()
    time.sleep(0.1)
    slow.stop()
    assert slow.stats.skipped > 0 and slow.stats.overruns > 0


def test_realtime_request_reports_instead_of_raising():
    report = apply_realtime(RealtimeRequest(sched_fifo=False, lock_memory=False, cpu=100000,
                                            timer_slack_ns=0))
    assert report.refused and "CPU 100000" in report.refused[0]
    assert not report.sched_fifo


def _effective_latency_us() -> int:
    fd = os.open(rt.CPU_DMA_LATENCY_DEVICE, os.O_RDONLY)
    try:
        return struct.unpack("i", os.read(fd, 4))[0]
    finally:
        os.close(fd)


@pytest.mark.skipif(not os.access(rt.CPU_DMA_LATENCY_DEVICE, os.W_OK),
                    reason="no writable /dev/cpu_dma_latency here")
def test_latency_request_holds_until_released():
    """The PM QoS request is in force (the kernel's effective value reads back) while the
    report holds it, and withdrawn by release()."""
    before = _effective_latency_us()
    report = apply_realtime(RealtimeRequest(sched_fifo=False, lock_memory=False,
                                            timer_slack_ns=0, cpu_dma_latency_us=7))
    try:
        assert any("wake-up latency" in a for a in report.applied)
        assert _effective_latency_us() == min(before, 7)
    finally:
        report.release()
    assert _effective_latency_us() == before
    assert report.held_fds == []


def test_latency_request_refused_without_the_device(monkeypatch, tmp_path):
    monkeypatch.setattr(rt, "CPU_DMA_LATENCY_DEVICE", str(tmp_path / "missing"))
    report = apply_realtime(RealtimeRequest(sched_fifo=False, lock_memory=False,
                                            timer_slack_ns=0, cpu_dma_latency_us=0))
    assert len(report.refused) == 1 and "wake-up latency" in report.refused[0]
    assert report.held_fds == []


def test_restore_gives_the_thread_its_policy_back_before_it_starts_another():
    """A run of several loops in one thread (``hybrid --learn``): after the first loop's
    restore(), a thread the caller starts runs under the normal policy, not SCHED_FIFO
    inherited from a loop that has ended."""
    seen: dict[str, object] = {}

    def loop_thread() -> None:
        before = (os.sched_getscheduler(0), os.sched_getaffinity(0))
        report = apply_realtime(RealtimeRequest(sched_fifo=True, priority=10,
                                                lock_memory=False, cpu=0))
        seen["fifo"] = report.sched_fifo
        seen["during"] = os.sched_getscheduler(0)
        report.restore()
        report.restore()                # a second call does nothing
        seen["after"] = (os.sched_getscheduler(0), os.sched_getaffinity(0))
        seen["before"] = before
        child = threading.Thread(
            target=lambda: seen.__setitem__("child", os.sched_getscheduler(0)))
        child.start()
        child.join()

    t = threading.Thread(target=loop_thread)
    t.start()
    t.join()
    if not seen["fifo"]:
        pytest.skip("SCHED_FIFO not permitted here")
    assert seen["during"] == os.SCHED_FIFO
    assert seen["after"] == seen["before"]
    assert seen["child"] == seen["before"][0] != os.SCHED_FIFO


def test_normal_scheduling_runs_a_block_off_sched_fifo_and_gives_it_back():
    """A node's configure (its model compiled and exercised) runs under the normal policy
    in a SCHED_FIFO executor thread, and the thread has its policy and priority back
    afterwards, after a block that raised too; under the normal policy it does nothing."""
    seen: dict[str, object] = {}

    def fifo_thread() -> None:
        report = apply_realtime(RealtimeRequest(sched_fifo=True, priority=12,
                                                lock_memory=False))
        seen["fifo"] = report.sched_fifo
        with normal_scheduling():
            seen["inside"] = os.sched_getscheduler(0)
            child = threading.Thread(   # work the block starts inherits the normal policy
                target=lambda: seen.__setitem__("child", os.sched_getscheduler(0)))
            child.start()
            child.join()
        seen["after"] = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
        with contextlib.suppress(RuntimeError), normal_scheduling():
            raise RuntimeError
        seen["after_raise"] = (os.sched_getscheduler(0),
                               os.sched_getparam(0).sched_priority)
        report.restore()

    def normal_thread() -> None:
        with normal_scheduling():
            seen["normal_inside"] = os.sched_getscheduler(0)

    for target in (fifo_thread, normal_thread):
        t = threading.Thread(target=target)
        t.start()
        t.join()
    assert seen["normal_inside"] == os.SCHED_OTHER
    if not seen["fifo"]:
        pytest.skip("SCHED_FIFO not permitted here")
    assert seen["inside"] == seen["child"] == os.SCHED_OTHER
    assert seen["after"] == seen["after_raise"] == (os.SCHED_FIFO, 12)
