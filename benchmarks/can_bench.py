#!/usr/bin/env python3
"""Benchmark of the CAN round trip through the bridge and the emulator; prints a markdown table.

For each case ``damper-hil emulate`` and ``damper-hil bridge`` (``mode: dyno``) run as
processes on a private ROS domain and a private ``udp_multicast`` bus (an interface-local
``ff11::`` group and a port of this process).  This process is the dyno: it sends
``DAMPER_STATE`` at 1 kHz from a :class:`~damper_emulator.realtime.loop.PeriodicLoop`
(``SCHED_FIFO`` when permitted), each sample tagged by a unique stroke (a sawtooth
−0.1 … +0.1 m in 10 µm steps, the Stroke signal's resolution: unique for 20 s), and a receive
thread records the arrival of the first ``DAMPER_FORCE`` whose ``StrokeUsed`` is each tag.

The measured window is ``--duration`` seconds of samples, with 2 s of samples sent before and
after it (the nodes' ``/diagnostics`` counters are read then, so that their differences span
the window and the sending never pauses).  Reported per case:

* round trip ``DAMPER_STATE`` sent → first ``DAMPER_FORCE`` computed from it arrives,
  p50 / p99 / max, as the dyno program sees it (its monotonic clock) and from the kernel's
  receive time stamp (``SO_TIMESTAMPNS``: without this process's own wake-up delay);
* samples sent, samples with no force (in timer mode a sample that another one replaces
  before the emulator's next tick gets none; the longest run of consecutive samples without
  a force tells a stall from that), DAMPER_FORCE frames and fault frames (bit 32);
* frames dropped by the receivers (wrong length, checksum, repeated counter) and lost (counter
  jumps): the bridge's DAMPER_STATE receiver (its ``/diagnostics``) and this dyno's
  DAMPER_FORCE receiver;
* the emulator's input timeouts and the sender's period p99;
* bus load of the emulator's periodic messages in the DBC (:func:`can_bridge.dbc.bus_load`,
  worst-case bit stuffing) at 500 kbit/s and 1 Mbit/s, and the load of the frames actually seen.

Cases: ``model`` (the bridge alone with ``model: true``: it steps the damper's model in its
receive thread and answers each sample at once, the README's dyno set-up), ``timer``
(``emulator.trigger: timer`` at 1 kHz, the emulator node behind the bridge over DDS) and
``input`` (``emulator.trigger: input``: one force per sample, the loopback dyno's set-up).
Each case's share of samples answered by a force computed from them (matched by
``StrokeUsed``) is reported.
Targets: ``model``: every sample answered, round trip p99 <= 1 ms (the force back within the
dyno's cycle); the emulator behind the bridge: p99 <= 2 ms; no lost frames over 60 s.

Usage: ``python benchmarks/can_bench.py [--duration S] [--case timer|input ...] [--json FILE]``
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from machine import cpu_name

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import can  # noqa: E402

from can_bridge.bus import BusConfig, ResilientBus  # noqa: E402
from can_bridge.codec import Encoder, Receiver  # noqa: E402
from can_bridge.core import FORCE, STATE  # noqa: E402
from can_bridge.dbc import REQUIRED_SIGNALS, ForceStatus, bus_load, frame_bits, load_database  # noqa: E402
from damper_emulator.realtime.loop import PeriodicLoop  # noqa: E402
from damper_emulator.realtime.rt import RealtimeRequest, apply_realtime  # noqa: E402
from damper_emulator.ros.launch import NodeProcess, node_command, ros_environment  # noqa: E402

#: case → (label, emulator trigger (None: the model in the bridge), ROS domain, bus offset);
#: domains 138, 139, 156 (the tests': 120..155)
CASES = {
    "model": ("model in the bridge (dyno)", None, 156, 2),
    "timer": ("emulator timer 1 kHz (HIL)", "timer", 138, 0),
    "input": ("emulator trigger input (loopback dyno)", "input", 139, 1),
}
#: the round trip's p99 target of each case [ms]
TARGETS_P99_MS = {"model": 1.0, "timer": 2.0, "input": 2.0}
RATE_HZ = 1000.0
WARMUP_S = 2.0               # samples sent before the measured window ...
COOLDOWN_S = 2.0             # ... and after it (the diagnostics snapshots are taken then)
DRAIN_S = 0.5
TAGS = 20000                 # distinct strokes: −0.1 … +0.1 m in 10 µm steps
STROKE_STEP = 1e-5
VELOCITY = STROKE_STEP * RATE_HZ          # the sawtooth's velocity [m/s]
BITRATES = (500_000, 1_000_000)


def private_channel(offset: int) -> str:
    """An interface-local group and a UDP port of this process (ports 17000..17389: clear of
    the tests' 10000..16999 and of the DDS ports of domains 40..139)."""
    pid = os.getpid()
    return (f"[ff11::d4:b{offset:x}:{pid >> 16:x}:{pid & 0xFFFF:x}]:"
            f"{17000 + (pid % 39) * 10 + offset}")


class Diagnostics:
    """The nodes' /diagnostics, read on demand from this process (own context, domain)."""

    def __init__(self, domain: int):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context

        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("can_bench_diagnostics", context=self.context)
        self.latest: dict[str, tuple[float, dict]] = {}

        def on_diag(msg) -> None:
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            for s in msg.status:
                self.latest[s.name.split(":")[0]] = (stamp, {kv.key: kv.value
                                                             for kv in s.values})

        self.node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
        from rclpy.executors import SingleThreadedExecutor
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def snapshot(self, names=("can_bridge", "damper_emulator"), timeout_s: float = 5.0):
        """The first status of each node published after now (None where none came)."""
        asked = time.time()
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if all(n in self.latest and self.latest[n][0] > asked for n in names):
                break
            self.executor.spin_once(timeout_sec=0.05)
        return {n: self.latest[n][1] if n in self.latest and self.latest[n][0] > asked
                else None for n in names}

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.context)


def _delta(after: dict | None, before: dict | None, key: str) -> int | None:
    if after is None or before is None or key not in after:
        return None
    return int(after[key]) - int(before[key])


def _pct(values_ms: np.ndarray) -> tuple[float, float, float]:
    if values_ms.size == 0:
        return (float("nan"),) * 3
    return (float(np.percentile(values_ms, 50)), float(np.percentile(values_ms, 99)),
            float(values_ms.max()))


def _longest_run(mask: np.ndarray) -> int:
    """Length of the longest run of True in ``mask``."""
    if not mask.any():
        return 0
    padded = np.concatenate(([0], mask.astype(np.int8), [0]))
    edges = np.flatnonzero(np.diff(padded))
    return int((edges[1::2] - edges[0::2]).max())


def measure(case: str, duration_s: float, workdir: Path, executor_fifo: int = 0) -> dict:
    label, trigger, domain, offset = CASES[case]
    channel = private_channel(offset)
    env = ros_environment(domain)
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    db = load_database()
    bridge = NodeProcess(f"bridge_{case}", node_command("bridge", {
        "can_interface": "udp_multicast", "can_channel": channel, "mode": "dyno",
        "model": trigger is None}), env, workdir)
    nodes = [bridge] if trigger is None else [
        NodeProcess(f"emulator_{case}", node_command("emulate", {
            "emulator.trigger": trigger}), env, workdir), bridge]
    names = ("can_bridge",) if trigger is None else ("can_bridge", "damper_emulator")
    if executor_fifo:
        # experiment: the bridge's executor (its main thread: /damper/force → DAMPER_FORCE)
        # on SCHED_FIFO too
        os.sched_setscheduler(bridge.pid, os.SCHED_FIFO, os.sched_param(executor_fifo))
    bus = ResilientBus(BusConfig(interface="udp_multicast", channel=channel))
    diag = None
    stop = threading.Event()
    try:
        if not bus.ensure_open():
            raise SystemExit(f"cannot open the bus: {bus.last_error}")
        diag = Diagnostics(domain)
        n_warm = int(WARMUP_S * RATE_HZ)
        n_meas = int(round(duration_s * RATE_HZ))
        n_total = n_warm + n_meas + int(COOLDOWN_S * RATE_HZ)
        sent_mono = np.zeros(n_total, dtype=np.int64)
        sent_wall = np.zeros(n_total, dtype=np.int64)
        recv_mono = np.zeros(n_total, dtype=np.int64)
        recv_wall = np.zeros(n_total, dtype=np.int64)
        latest_k = np.full(TAGS, -1, dtype=np.int64)
        enc = Encoder(db, STATE)
        force_rx = Receiver(db, [FORCE])
        force_id = db.get_message_by_name(FORCE).frame_id
        no_model = int(ForceStatus.FORCE_TIMEOUT | ForceStatus.NO_INPUT)
        anomalies: list[tuple[int, str, str]] = []
        seen = {"frames": 0, "forces": 0, "fault_frames": 0, "first": 0, "last": 0,
                "rt": None, "connected": False}

        def receive() -> None:
            seen["rt"] = apply_realtime(RealtimeRequest(sched_fifo=True, priority=60,
                                                        lock_memory=False))
            while not stop.is_set():
                msg = bus.recv(0.1)
                if msg is None:
                    continue
                mono = time.monotonic_ns()
                seen["frames"] += 1
                seen["first"] = seen["first"] or mono
                seen["last"] = mono
                if msg.arbitration_id != force_id:
                    continue
                lost = force_rx.drops.lost
                got = force_rx.accept(msg.arbitration_id, msg.data)
                if got is None or force_rx.drops.lost != lost:
                    anomalies.append((mono, "dropped" if got is None else
                                      f"lost {force_rx.drops.lost - lost}",
                                      bytes(msg.data).hex()))
                if got is None:
                    continue
                values = got.values
                bits = int(values["Status"])
                if bits & ForceStatus.FORCE_TIMEOUT:
                    seen["fault_frames"] += 1
                if bits & no_model:
                    continue
                seen["forces"] += 1
                seen["connected"] = True
                tag = int(round(values["StrokeUsed"] / STROKE_STEP)) + TAGS // 2
                if 0 <= tag < TAGS:
                    k = latest_k[tag]
                    if k >= 0 and recv_mono[k] == 0:
                        recv_mono[k] = mono
                        recv_wall[k] = int(round(msg.timestamp * 1e9))

        rx = threading.Thread(target=receive, name="can-bench-rx", daemon=True)
        rx.start()
        # connect: until the emulator answers through the bridge
        deadline = time.monotonic() + 90
        while not seen["connected"]:
            for n in nodes:
                if n.poll() is not None:
                    raise SystemExit(f"{n.name} stopped:\n{n.log_tail()}")
            if time.monotonic() > deadline:
                raise SystemExit("no DAMPER_FORCE from the emulator within 90 s:\n"
                                 + "\n".join(n.log_tail() for n in nodes))
            data, _ = enc.encode(Stroke=-0.1, Velocity=0.0)
            bus.send(can.Message(arbitration_id=enc.frame_id, data=data,
                                 is_extended_id=False))
            time.sleep(0.01)
        counter = [0]

        def tick(_now: int) -> None:
            k = counter[0]
            if k >= n_total:
                raise StopIteration
            raw = k % TAGS
            data, _ = enc.encode(Stroke=(raw - TAGS // 2) * STROKE_STEP, Velocity=VELOCITY)
            latest_k[raw] = k
            sent_wall[k] = time.time_ns()
            sent_mono[k] = time.monotonic_ns()
            bus.send(can.Message(arbitration_id=enc.frame_id, data=data,
                                 is_extended_id=False))
            counter[0] = k + 1

        loop = PeriodicLoop(1.0 / RATE_HZ, tick, name="can-bench-tx",
                            realtime=RealtimeRequest(sched_fifo=True, priority=70,
                                                     lock_memory=False))

        def wait_for_sample(k: int) -> None:
            while loop.running and counter[0] < k:
                time.sleep(0.005)
                if any(n.poll() is not None for n in nodes):
                    raise SystemExit("a node stopped:\n"
                                     + "\n".join(n.log_tail() for n in nodes))

        loop.start()
        # the nodes' counters: snapshots while the samples flow (warm-up, cool-down), so
        # that their differences span the measured window and no silence
        wait_for_sample(n_warm // 4)
        before = diag.snapshot(names)
        wait_for_sample(n_warm)
        rx_before = force_rx.drops.copy()
        frames_before, faults_before = seen["frames"], seen["fault_frames"]
        t_start = time.monotonic_ns()
        wait_for_sample(n_warm + n_meas)
        t_end = time.monotonic_ns()
        frames_seen = seen["frames"] - frames_before
        fault_frames = seen["fault_frames"] - faults_before
        rx_after = force_rx.drops.copy()
        after = diag.snapshot(names)
        wait_for_sample(n_total)
        loop.stop()
        if loop.error is not None and not isinstance(loop.error, StopIteration):
            raise SystemExit(f"send loop failed: {loop.error!r}")
        time.sleep(DRAIN_S)
        for n in nodes:
            if n.poll() is not None:
                raise SystemExit(f"{n.name} stopped during the run:\n{n.log_tail()}")
    finally:
        stop.set()
        if diag is not None:
            diag.close()
        bus.close()
        for n in reversed(nodes):
            n.stop()

    index = np.arange(n_total)
    measured = (index >= n_warm) & (index < n_warm + n_meas)
    got = measured & (recv_mono > 0)
    lat_app = (recv_mono[got] - sent_mono[got]) * 1e-6
    lat_kernel = (recv_wall[got] - sent_wall[got]) * 1e-6
    missing = measured & (recv_mono == 0)
    # p99 per second of the measured window
    secs = []
    for a in range(n_warm, n_warm + n_meas - int(RATE_HZ) + 1, int(RATE_HZ)):
        w = got[a:a + int(RATE_HZ)]
        lat_w = (recv_mono[a:a + int(RATE_HZ)][w] - sent_mono[a:a + int(RATE_HZ)][w]) * 1e-6
        secs.append(float(np.percentile(lat_w, 99)) if lat_w.size else float("inf"))
    rx_d = rx_after
    s = loop.stats.summary()
    bridge_b, bridge_a = before["can_bridge"], after["can_bridge"]
    emu_b, emu_a = before.get("damper_emulator"), after.get("damper_emulator")
    window_s = (t_end - t_start) * 1e-9
    bits = frame_bits(8)
    row = {
        "case": label, "trigger": trigger, "duration_s": duration_s, "channel": channel,
        "samples_sent": int(counter[0]), "samples_measured": int(measured.sum()),
        "round_trip_ms": dict(zip(("p50", "p99", "max"), _pct(lat_app))),
        "round_trip_kernel_stamp_ms": dict(zip(("p50", "p99", "max"), _pct(lat_kernel))),
        "target_p99_ms": TARGETS_P99_MS[case],
        "round_trip_over_target": int((lat_app > TARGETS_P99_MS[case]).sum()),
        "p99_per_second_ms": secs,
        "seconds_meeting_p99": int(sum(x <= TARGETS_P99_MS[case] for x in secs)),
        "bridge_executor_fifo": executor_fifo,
        "samples_without_force": int(missing.sum()),
        "answered_share": float(got.sum() / max(int(measured.sum()), 1)),
        "longest_run_without_force": _longest_run(missing),
        "force_frames": int(rx_d.accepted - rx_before.accepted),
        "fault_frames": int(fault_frames),
        "dyno_rx": {"length": rx_d.length - rx_before.length,
                    "checksum": rx_d.checksum - rx_before.checksum,
                    "counter": rx_d.counter - rx_before.counter,
                    "lost": rx_d.lost - rx_before.lost},
        "bridge_rx": {k: _delta(bridge_a, bridge_b, key) for k, key in (
            ("length", "dropped_length"), ("checksum", "dropped_checksum"),
            ("counter", "dropped_counter"), ("lost", "lost_frames"))},
        "bridge": {k: _delta(bridge_a, bridge_b, k) for k in (
            "states_in", "forces_out", "fault_frames_out", "state_timeouts",
            "force_timeouts", "tx_failed")},
        "bridge_realtime": bridge_a.get("realtime") if bridge_a else None,
        "emulator": {k: _delta(emu_a, emu_b, k) for k in (
            "inputs_accepted", "timeouts", "fault_outputs", "overruns")},
        "emulator_realtime": emu_a.get("realtime") if emu_a else None,
        "sender_period_p99_us": s.period_p99_us, "sender_period_max_us": s.period_max_us,
        "sender_realtime": loop.report.summary(),
        "receiver_realtime": seen["rt"].summary() if seen["rt"] else None,
        "frames_per_s": frames_seen / window_s,
        # DAMPER_FORCE frames this dyno dropped or that came after a counter jump: time
        # from the start of the sending [s] (negative: before), what, payload
        "dyno_rx_events": [((t - t_start) * 1e-9, what, data) for t, what, data in anomalies],
        "measured_bus_load": {str(b): frames_seen / window_s * bits / b for b in BITRATES},
    }
    row["lost_frames"] = sum(v or 0 for v in (*row["dyno_rx"].values(),
                                              *row["bridge_rx"].values()))
    return row


def _fmt3(d: dict) -> str:
    return f"{d['p50']:.2f} / {d['p99']:.2f} / {d['max']:.1f} ms"


def _counts(d: dict) -> str:
    def one(v):
        return "?" if v is None else str(v)
    return (f"{one(d['length'])} / {one(d['checksum'])} / {one(d['counter'])}, "
            f"lost {one(d['lost'])}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per case "
                    "(the measured window; 2 s of samples before and after it are not "
                    "measured)")
    ap.add_argument("--case", choices=list(CASES), action="append",
                    help="run only these cases (default: timer and input)")
    ap.add_argument("--json", type=Path, help="also write the results here")
    ap.add_argument("--bridge-executor-fifo", type=int, default=0, metavar="PRIO",
                    help="experiment: put the bridge's executor thread (its main thread) on "
                         "SCHED_FIFO PRIO as well (needs the permission; default: leave it)")
    args = ap.parse_args()
    if not args.duration > 0:
        ap.error("--duration must be positive")
    sys.setswitchinterval(1e-4)     # the sender and receiver threads share the GIL
    cases = args.case or list(CASES)
    db = load_database()
    rows = []
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        for i, case in enumerate(cases):
            print(f"[{i + 1}/{len(cases)}] {CASES[case][0]}, {args.duration:g} s ...",
                  file=sys.stderr, flush=True)
            rows.append(measure(case, args.duration, Path(tmp), args.bridge_executor_fifo))
    load_after = os.getloadavg()
    loads = {b: {"all": bus_load(db, b, REQUIRED_SIGNALS),
                 "dyno": bus_load(db, b, ["DAMPER_STATE", "DAMPER_FORCE"])} for b in BITRATES}

    print("# CAN round trip through the bridge (and the emulator)\n")
    print(f"CAN round trip DAMPER_STATE → bridge (→ emulator → bridge) → DAMPER_FORCE, "
          f"{args.duration:g} s per case at {RATE_HZ:g} Hz, udp_multicast (interface-local), "
          f"dyno in a separate process; {cpu_name()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, load average "
          f"(1 min) {load_before[0]:.2f} before, {load_after[0]:.2f} after"
          + (f"; bridge executor thread on SCHED_FIFO {args.bridge_executor_fifo}"
             if args.bridge_executor_fifo else "") + "\n")
    print("| case | samples measured | round trip p50 / p99 / max | same, kernel rx stamp | "
          "samples over the target | seconds with p99 ≤ target | answered by StrokeUsed | "
          "samples with no force (longest run) | "
          "DAMPER_FORCE frames "
          "(fault frames) | dropped at the bridge: length / checksum / counter, lost | "
          "dropped at the dyno: length / checksum / counter, lost | emulator input timeouts | "
          "sender period p99 |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['samples_measured']} | {_fmt3(r['round_trip_ms'])} | "
              f"{_fmt3(r['round_trip_kernel_stamp_ms'])} | {r['round_trip_over_target']} "
              f"(> {r['target_p99_ms']:g} ms) | "
              f"{r['seconds_meeting_p99']} of {len(r['p99_per_second_ms'])} | "
              f"{100 * r['answered_share']:.2f} % | "
              f"{r['samples_without_force']} ({r['longest_run_without_force']}) | "
              f"{r['force_frames']} ({r['fault_frames']}) | {_counts(r['bridge_rx'])} | "
              f"{_counts(r['dyno_rx'])} | "
              f"{'–' if r['emulator']['timeouts'] is None else r['emulator']['timeouts']} | "
              f"{r['sender_period_p99_us']:.0f} µs |")
    print("\nTargets: the model in the bridge answers every sample, round trip p99 ≤ 1 ms "
          "(the force within the dyno's cycle); the emulator behind the bridge p99 ≤ 2 ms; "
          "no lost frames over 60 s.")
    for r in rows:
        verdict = "met" if r["round_trip_ms"]["p99"] <= r["target_p99_ms"] else "NOT met"
        lost = (f"{r['lost_frames']} CAN frames lost or dropped" if r["lost_frames"]
                else "no CAN frames lost or dropped")
        loads_seen = ", ".join(f"{v * 100:.1f} % of {int(b) // 1000} kbit/s"
                               for b, v in r["measured_bus_load"].items())
        print(f"- {r['case']}: p99 {verdict}; {lost}; {r['samples_without_force']} samples "
              f"without a force (longest run {r['longest_run_without_force']}); "
              f"{r['frames_per_s']:.0f} frames/s seen on the bus ({loads_seen}, worst-case "
              "stuffing)")
    print("\n| bit rate | bus load, the emulator's periodic messages | DAMPER_STATE + "
          "DAMPER_FORCE only |")
    print("|---|---|---|")
    for b in BITRATES:
        print(f"| {b // 1000} kbit/s | {loads[b]['all'] * 100:.1f} % | "
              f"{loads[b]['dyno'] * 100:.1f} % |")
    for r in rows:
        print(f"\n{r['case']}: sender {r['sender_realtime']}; bridge receive thread "
              f"{r['bridge_realtime']}"
              + ("; no emulator node" if r["trigger"] is None
                 else f"; emulator {r['emulator_realtime'] or 'without a loop (input)'}"))
    if args.json:
        doc = {"rows": rows, "bus_load": {str(b): v for b, v in loads.items()}}
        args.json.write_text(json.dumps(doc, indent=2) + "\n")


if __name__ == "__main__":
    main()
