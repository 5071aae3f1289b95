#!/usr/bin/env python3
"""Benchmark of the damper_emulator node over real DDS; prints a markdown table.

For each case the emulator runs in its own process (``damper-hil emulate``, ``trigger:
timer``, or ``trigger: input`` in the last case); this process publishes ``/damper/state``
at 1 kHz from its own fixed-rate loop thread, each sample tagged by a unique velocity, and
an independent rclpy node in a child process receives ``/damper/force``.  Each case runs
once per consumer kind, one consumer at a time, as a deployment has one consumer of the
force (two consumers on two cores measured each other: in one run beside each other, the
real-time consumer's p99 was 746 µs, alone 516 µs):

* a real-time consumer, as the project's own (the bridge, the ride) take the force:
  SCHED_FIFO, the serialized message taken from rclpy's wait set without an executor,
  stamped on arrival, decoded after the run by rclpy's own deserializer;
* a consumer as rclpy's examples write one: a callback served by a single-threaded
  executor that holds the node, as ``rclpy.spin(node)`` serves it (the executor's Python on
  every message).

The sender serializes each sample with rclpy's serializer, notes the time, and hands the
bytes to DDS; the latency runs from there to the consumer's take.

* achieved rate and loop period p50 / p99 / max, p99 of |period − nominal|, overruns
  (periods > 2 nominal) — from the emulator's own record of every period
  (``emulator.stats_file``) in the real-time consumer's run;
* state → force latency p50 / p99: from publishing a sample to receiving the first force
  computed from it, measured in this (separate) process.

Cases: 1 kHz with the node's default real-time settings (SCHED_FIFO, mlockall, CPU wake-up
latency request ``cpu_dma_latency_us: 0``, the ticks phase-locked 0.2 ms after the input's
arrivals), the same without the phase lock, 1 kHz without SCHED_FIFO and mlockall, 1 kHz
with none of them, 2 kHz with all of them, and the input trigger (one force per sample, no
loop: its loop columns are empty) with all of them.  Targets at 1 kHz with the node's
defaults: p99 period error <= 100 us, overruns <= 0.1 % over 60 s, state→force latency p99
<= 1 ms (timer trigger) and <= 0.5 ms (input trigger).

Usage: ``python benchmarks/node_bench.py [--duration S] [--json FILE]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
from machine import cpu_name

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from damper_emulator.realtime.loop import load_record  # noqa: E402
from damper_emulator.ros.launch import NodeProcess, node_command, ros_environment  # noqa: E402


class Case(NamedTuple):
    label: str
    rate_hz: float
    fifo: bool                 # SCHED_FIFO + mlockall
    latency_us: int            # CPU wake-up latency request [µs], or -1
    trigger: str
    phase_lock_us: float = 200.0
    targeted: bool = False     # the node's defaults: the latency targets apply


CASES = (
    Case("1 kHz, SCHED_FIFO", 1000.0, True, 0, "timer", targeted=True),
    Case("1 kHz, SCHED_FIFO, no phase lock", 1000.0, True, 0, "timer", phase_lock_us=0.0),
    Case("1 kHz, no SCHED_FIFO", 1000.0, False, 0, "timer"),
    Case("1 kHz, no real-time settings", 1000.0, False, -1, "timer"),
    Case("2 kHz, SCHED_FIFO", 2000.0, True, 0, "timer"),
    Case("input trigger, SCHED_FIFO", 1000.0, True, 0, "input", targeted=True),
)
#: the state→force latency's p99 target of each trigger [µs]
TARGET_LATENCY_P99_US = {"timer": 1000.0, "input": 500.0}
INPUT_RATE_HZ = 1000.0


def input_period_s(duration_s: float) -> float:
    """The sender's period: one input period longer over the run than at
    :data:`INPUT_RATE_HZ`, so that the inputs' phase against a timer-triggered emulator's
    ticks sweeps once through a whole period.  (At the same rate the phase stays where the
    two loops happened to start, and the latency's median then came out anywhere from
    0.39 to 0.86 ms from one run to the next.)"""
    return (1.0 + 1.0 / (duration_s * INPUT_RATE_HZ)) / INPUT_RATE_HZ

VELOCITY_TAG = 1e-6          # sample k carries velocity k * VELOCITY_TAG [m/s]
#: the two consumers of /damper/force, one per run, and their columns' key suffix: a
#: real-time one (a wait set; its run gives the loop's columns too), and rclpy's executor
#: (a callback served by a single-threaded executor)
RECEIVERS = {"waitset": "_waitset", "executor": ""}
#: the wait-set receiver's SCHED_FIFO priority (below the emulator's loop, 80)
RECEIVER_PRIORITY = 70


def receive(domain: int, n_max: int, duration_s: float, out: str, ready,
            waitset: bool = False) -> None:
    """Child process: record when each tagged force arrives (CLOCK_MONOTONIC is shared by
    all processes of the machine).  A consumer as rclpy's examples write one (a callback
    served by a single-threaded executor: its Python on every message), or, with
    ``waitset``, as a real-time one would (SCHED_FIFO, serialized messages taken from
    rclpy's wait set without an executor, stamped as taken and decoded after the run)."""
    os.environ.update({"ROS_DOMAIN_ID": str(domain),
                       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.impl.implementation_singleton import rclpy_implementation as impl
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos

    sys.setswitchinterval(1e-4)
    rclpy.init()
    node = rclpy.create_node("node_bench_receiver")
    received = np.zeros(n_max, dtype=np.int64)

    def on_force(msg: JointState) -> None:
        now = time.monotonic_ns()
        k = int(round(msg.velocity[0] / VELOCITY_TAG))
        if 0 < k < n_max and received[k] == 0:
            received[k] = now

    sub = node.create_subscription(JointState, topics.FORCE, on_force,
                                   control_qos(topics.CONTROL_DEPTH), raw=waitset)
    arrivals: list[tuple[int, bytes]] = []
    while node.count_publishers(topics.FORCE) == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    end = time.monotonic() + duration_s + 5.0
    if waitset:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RECEIVER_PRIORITY))
        wait_set = impl.WaitSet(1, 0, 0, 0, 0, 0, node.context.handle)
        ready.set()
        while time.monotonic() < end:
            wait_set.clear_entities()
            with sub.handle:
                wait_set.add_subscription(sub.handle)
            wait_set.wait(50_000_000)
            while True:
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, sub.raw)
                if taken is None:
                    break
                arrivals.append((time.monotonic_ns(), taken[0]))
    else:
        # as ``rclpy.spin(node)`` serves it: one executor that holds the node throughout
        # (``rclpy.spin_once(node)`` adds the node to the global executor and removes it
        # again on every call, a wait set rebuilt and a guard condition more per message)
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
        ready.set()
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
    for now, data in arrivals:
        msg = deserialize_message(data, JointState)
        k = int(round(msg.velocity[0] / VELOCITY_TAG))
        if 0 < k < n_max and received[k] == 0:
            received[k] = now
    np.save(out, received)
    node.destroy_node()
    rclpy.shutdown()


def measure(case: Case, duration_s: float, workdir: Path, domain: int, kind: str) -> dict:
    """One run of a case with the consumer ``kind`` (:data:`RECEIVERS`)."""
    import multiprocessing

    import rclpy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState

    from damper_emulator import topics
    from damper_emulator.realtime.loop import PeriodicLoop
    from damper_emulator.realtime.rt import RealtimeRequest
    from damper_emulator.ros.common import control_qos

    rate_hz, fifo, trigger = case.rate_hz, case.fifo, case.trigger
    tag = f"{domain}_{kind}"
    stats_file = workdir / f"stats_{tag}.npz"
    recv_file = workdir / f"recv_{tag}.npy"
    env = ros_environment(domain)
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    emu = NodeProcess("emulator", node_command("emulate", {
        "emulator.rate_hz": rate_hz, "emulator.sched_fifo": fifo,
        "emulator.lock_memory": fifo, "emulator.cpu_dma_latency_us": case.latency_us,
        "emulator.phase_lock_us": case.phase_lock_us,
        "emulator.stats_file": str(stats_file), "emulator.trigger": trigger,
        "emulator.input_timeout_s": 1.0}), env, workdir)
    n_max = int(duration_s * INPUT_RATE_HZ) + 10
    ctx = multiprocessing.get_context("spawn")
    ready = ctx.Event()
    receiver = ctx.Process(target=receive, args=(
        domain, n_max, duration_s, str(recv_file), ready, kind == "waitset"))
    receiver.start()
    rclpy.init()
    node = rclpy.create_node("node_bench_sender")
    pub = node.create_publisher(JointState, topics.STATE, control_qos(topics.CONTROL_DEPTH))
    deadline = time.monotonic() + 60
    while node.count_subscribers(topics.STATE) == 0 or not ready.is_set():
        time.sleep(0.05)
        if time.monotonic() > deadline or emu.poll() is not None:
            raise SystemExit(f"emulator or receiver did not start:\n{emu.log_tail()}")
    time.sleep(1.0)                       # let the emulator's loop reach steady state
    sent = np.zeros(n_max, dtype=np.int64)
    counter = [0]
    msg = JointState()
    msg.name = ["damper"]

    def tick(now: int) -> None:
        k = counter[0] = counter[0] + 1
        if k >= n_max - 1:
            raise StopIteration
        msg.position = [0.0]
        msg.velocity = [k * VELOCITY_TAG]
        # stamped as a bridge or a ride stamps its states: the input trigger steps the
        # model by the stamps' differences, and refuses a stamp not after the last
        stamp = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        data = serialize_message(msg)
        sent[k] = time.monotonic_ns()
        pub.publish(data)

    loop = PeriodicLoop(input_period_s(duration_s), tick, name="bench-input",
                        realtime=RealtimeRequest(sched_fifo=fifo, priority=60,
                                                 lock_memory=False))
    loop.start()
    time.sleep(duration_s)
    loop.stop()
    receiver.join(duration_s + 30)
    node.destroy_node()
    rclpy.shutdown()
    emu.stop()
    received = np.load(recv_file)
    ok = (sent > 0) & (received > 0)
    lat_us = (received[ok] - sent[ok]) / 1e3
    suffix = RECEIVERS[kind]
    row: dict = {"rate_hz": rate_hz, "sched_fifo": fifo, "trigger": trigger, "realtime": "",
                 "ticks": None, "samples": int((sent > 0).sum()),
                 f"latency{suffix}_p50_us": (float(np.percentile(lat_us, 50)) if lat_us.size
                                             else float("nan")),
                 f"latency{suffix}_p99_us": (float(np.percentile(lat_us, 99)) if lat_us.size
                                             else float("nan")),
                 f"samples_without_force{suffix}": int(((sent > 0) & (received == 0)).sum())}
    if trigger == "timer":           # the input trigger has no loop, and no record of it
        z, s = load_record(stats_file)
        row.update({
            "realtime": str(z["realtime"]),
            "ticks": s.ticks, "achieved_rate_hz": s.achieved_rate_hz,
            "period_p50_us": s.period_p50_us, "period_p99_us": s.period_p99_us,
            "period_max_us": s.period_max_us, "error_p99_us": s.error_p99_us,
            "wake_p50_us": s.wake_p50_us, "wake_p99_us": s.wake_p99_us,
            "work_p99_us": s.work_p99_us, "work_max_us": s.work_max_us,
            "overruns": s.overruns,
            "overrun_percent": 100.0 * s.overruns / z["periods_ns"].size,
            "skipped": s.skipped})
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per case")
    ap.add_argument("--json", type=Path, help="also write the results here")
    ap.add_argument("--case", type=int, action="append",
                    help="run only these cases (0-based; default all)")
    args = ap.parse_args()
    cases = [CASES[i] for i in args.case] if args.case else list(CASES)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, case in enumerate(cases):
            r: dict = {}
            for j, kind in enumerate(RECEIVERS):
                print(f"[{i + 1}/{len(cases)}] {case.label}, {kind} consumer, "
                      f"{args.duration:g} s ...", file=sys.stderr, flush=True)
                # the first run's (real-time consumer's) loop columns are kept
                r = {**measure(case, args.duration, Path(tmp), 60 + 2 * i + j, kind), **r}
            r.update(case=case.label, targeted=case.targeted)
            rows.append(r)
    print("# The emulator node over DDS\n")
    print(f"Emulator node, {args.duration:g} s per case, input at {INPUT_RATE_HZ:g} Hz "
          f"(its clock one period slow over the run: an unlocked timer meets every phase) from "
          f"a separate process, one consumer per run; the latency from the serialized "
          f"sample handed to DDS to the consumer's take (earlier versions of this benchmark "
          f"timed from before the sender's serialization, two consumers at once); "
          f"{cpu_name()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}\n")
    print("| case | achieved rate | period p50 / p99 / max | p99 period error | overruns "
          "(> 2 periods) | wake-up latency p50 / p99 | tick work p99 / max | state→force "
          "p50 / p99, real-time consumer | state→force p50 / p99, executor consumer | input "
          "samples superseded before a tick |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        loop = (f"{r['achieved_rate_hz']:.2f} Hz | {r['period_p50_us']:.0f} / "
                f"{r['period_p99_us']:.0f} / {r['period_max_us']:.0f} µs | "
                f"{r['error_p99_us']:.0f} µs | {r['overruns']} ({r['overrun_percent']:.3f} %) | "
                f"{r['wake_p50_us']:.0f} / {r['wake_p99_us']:.0f} µs | "
                f"{r['work_p99_us']:.0f} / {r['work_max_us']:.0f} µs"
                if r["ticks"] is not None else "– | – | – | – | – | –")
        print(f"| {r['case']} | {loop} | "
              f"{r['latency_waitset_p50_us']:.0f} / {r['latency_waitset_p99_us']:.0f} µs | "
              f"{r['latency_p50_us']:.0f} / {r['latency_p99_us']:.0f} µs | "
              f"{r['samples_without_force_waitset']} of {r['samples']} |")
    print()
    for r in rows:
        if r["targeted"]:
            target = TARGET_LATENCY_P99_US[r["trigger"]]
            for kind, suffix in RECEIVERS.items():
                p99 = r[f"latency{suffix}_p99_us"]
                print(f"- {r['case']}, {kind} consumer: state→force p99 {p99:.0f} µs, target "
                      f"≤ {target:g} µs: {'met' if p99 <= target else 'NOT met'}")
    for r in rows:
        if r["realtime"]:
            print(f"\n{r['case']}: real-time settings {r['realtime']}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
