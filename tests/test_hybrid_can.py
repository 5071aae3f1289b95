"""A damper in the loop over a real python-can bus: ``damper-hil virtual-rig`` and
``damper-hil hybrid`` as processes on a ``udp_multicast`` group of their own (``socketcan``
on ``vcan0`` where the kernel has it), a tap of the test's on the same bus, the bag read
back by rosbags.

The rides are short (the tests' budget); the 20 s ride of the targets is the benchmark's
(benchmarks/hybrid_bench.py).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import re
import subprocess
import sys
import threading
import warnings
from pathlib import Path

import can
import numpy as np
import pytest
from host_stalls import RUNS_THROUGH_STALLS, Sentinels

from can_bridge.bus import BusConfig, socketcan_problem
from can_bridge.codec import Receiver
from can_bridge.dbc import HYBRID_SIGNALS, load_database
from can_bridge.tap import BusTap
from damper_emulator.model.compressible import DamperModel
from ride_sim.hybrid.params import RigParams, SafetyParams
from ride_sim.hybrid.recorder import CSV_COLUMNS

pytestmark = [pytest.mark.can, pytest.mark.ros]
#: the ROS domain of the ride's live /diagnostics (tests/test_bridge.py uses 130..137)
DOMAIN = 143

CLI = [sys.executable, "-m", "damper_hil.cli"]
#: a short run: the identification and the ride shortened, the rest the defaults
SHORT = """/**:
  ros__parameters:
    hybrid: {ramp_s: 0.5, settle_s: 0.3, connect_timeout_s: 3.0}
    compensator: {identify_s: 1.5}
"""
OFFSETS = {"ride": 0, "cut": 1, "unstable": 2, "nodyno": 3, "dyno": 4, "hoststall": 6,
           "restart": 7, "faults": 8}


def udp_channel(offset: int) -> str:
    """An interface-local group and a UDP port private to this process and ``offset``
    (python-can binds the port on every address: the port separates concurrent set-ups;
    17000..21999 is clear of the DDS ports of the ROS domains the tests use)."""
    pid = os.getpid()
    return f"[ff11::d6:{offset:x}:{pid & 0xFFFF:x}]:{17000 + (pid % 500) * 10 + offset}"


def start_rig(args) -> subprocess.Popen:
    """``virtual-rig ARGS``, returned once it runs its loop (its start-up line: with an
    empty numba cache it compiles the specimen first)."""
    rig = subprocess.Popen([*CLI, "virtual-rig", *args], stdout=subprocess.DEVNULL,
                           stderr=subprocess.PIPE, text=True)
    assert rig.stderr is not None
    lines = []
    for line in rig.stderr:                     # ends when the process does
        lines.append(line)
        if line.startswith("[virtual-rig] on "):
            break
    else:
        raise AssertionError(f"virtual-rig did not start: {''.join(lines)}")
    threading.Thread(target=rig.stderr.read, daemon=True).start()   # keep the pipe drained
    return rig


def read_rig_stats(rig_json: Path) -> dict:
    """What ``virtual-rig --json`` wrote (:class:`can_bridge.virtual_rig.RigStats`; its
    ``stalls``: each time it fell behind its cycle, as (start [s], length [ms])); empty
    where it wrote nothing."""
    return json.loads(rig_json.read_text()) if rig_json.exists() else {}


#: The host's own jitter beside a stall of the rig's [ms].
HOST_JITTER_MS = 10.0


def _stopped(proc, doc_path: Path) -> tuple[dict, str, float | None] | None:
    """A run that stopped (exit 3) and wrote ``doc_path``: its JSON, the reason, and the
    pause of the feedback or of the host's loop the reason names [ms] (None: another
    reason); None for a run that did not stop."""
    if proc.returncode != 3 or not doc_path.exists():
        return None
    doc = json.loads(doc_path.read_text())
    pause = re.search(r"(?:DYNO_FEEDBACK|DYNO_COMMAND) for (\d+) ms", doc["reason"])
    return doc, doc["reason"], float(pause.group(1)) if pause else None


def host_paused_before_the_stop(out: Path, within_s: float = 0.1) -> float | None:
    """The longest pause of the host's cycles [ms] in the last ``within_s`` of the run's
    record (hybrid.csv's send times), when it exceeds :data:`HOST_JITTER_MS`; else None.
    After such a pause the host runs its backlog faster than the rig's cycle, and the rig
    chases the demand: a limit the safety layer then stops at is the host's timing."""
    sent = np.loadtxt(out / "hybrid.csv", delimiter=",", skiprows=1, usecols=0, ndmin=1)
    sent = sent[sent >= sent[-1] - within_s * 1e9] if sent.size else sent
    if sent.size < 2:
        return None
    pause_ms = float(np.diff(sent).max()) * 1e-6
    return pause_ms if pause_ms > HOST_JITTER_MS else None


def machine_stalled(proc, out: Path, rig_stats: dict, host_stalls) -> str | None:
    """Why a stopped run says nothing about the code, or None:

    * the watchdog stopped it for a pause of the feedback, or the host stopped for a pause
      of its own loop, and for most of that pause the rig fell behind its cycle (its own
      log) or a sentinel thread at real-time priority woke late (:class:`Sentinels`): the
      virtual machine halted them;
    * stalls left the identification too little (the host's account, in hybrid.json).

    What the code guarantees is the stop."""
    if (stop := _stopped(proc, out / "hybrid.json")) is None:
        return None
    doc, reason, pause_ms = stop
    if "from stalls" in reason:
        return reason
    if pause_ms is None:
        return None
    if "safety" not in doc:         # stopped while the twin learned: no stop time to match
        return _sentinel_late_by(reason, pause_ms, host_stalls)
    stopped = doc["safety"]["stopped_at_s"]
    started = stopped - pause_ms * 1e-3
    witnesses = [("the rig fell behind", s) for s in rig_stats.get("stalls", [])]
    witnesses += [("a sentinel woke late", s) for s in host_stalls]
    for who, (start, length_ms) in witnesses:
        overlap = min(stopped, start + length_ms * 1e-3) - max(started, start)
        if overlap * 1e3 >= (stopped - started) * 1e3 - HOST_JITTER_MS:
            return f"{reason}; {who} by {length_ms:.0f} ms then"
    return None


def run_pair(tmp: Path, bus: BusConfig, rig_args=(), hybrid_args=(), tap=False, env=None):
    """``virtual-rig`` in the background, then ``hybrid`` to its end; returns the hybrid
    process, its output folder, the rig's statistics and the tap (or None).  ``{run}`` in
    ``hybrid_args`` is the run's own folder.  A run that the
    machine stalled (:func:`machine_stalled`) runs again, with a warning."""
    for run in range(1, RUNS_THROUGH_STALLS + 1):
        folder = tmp / f"run{run}"
        folder.mkdir(parents=True)
        sentinels = Sentinels(folder)
        try:
            result = _run_pair_once(folder, bus, rig_args, hybrid_args, tap, env)
        finally:
            sentinels.close()
        why = machine_stalled(result[0], result[1], result[2], sentinels.stalls)
        if why is None:
            return result
        warnings.warn(f"run {run} stopped by a stall of the machine: {why}", stacklevel=2)
    return result


def _run_pair_once(tmp: Path, bus: BusConfig, rig_args, hybrid_args, tap, env):
    config = tmp / "short.yaml"
    config.write_text(SHORT)
    bus_args = ["--can-interface", bus.interface, "--can-channel", bus.channel]
    rig_json = tmp / "rig.json"
    rig = start_rig([*bus_args, "--config", str(config), "--json", str(rig_json), *rig_args])
    listener = BusTap(bus) if tap else None
    out = tmp / "out"
    try:
        proc = subprocess.run([*CLI, "hybrid", "--out", str(out), "--config", str(config),
                               *bus_args, *(a.replace("{run}", str(tmp)) for a in hybrid_args)],
                              capture_output=True, text=True, timeout=300, env=env)
    finally:
        rig.send_signal(2)
        try:
            rig.wait(timeout=20)
        except subprocess.TimeoutExpired:
            rig.kill()
            rig.wait()
        if listener is not None:
            listener.close()
    rig_stats = read_rig_stats(rig_json)
    return proc, out, rig_stats, listener


@pytest.fixture(scope="module")
def bus_db():
    return load_database(required=HYBRID_SIGNALS)


@pytest.fixture(scope="module")
def ride(tmp_path_factory):
    """A compensated 3 s ride on the virtual rig's sport prototype, with the twin learned
    from it first (``--learn``), every 100th feedback frame corrupted on the way, its live
    ``/diagnostics`` (``--ros``) received by a node of the test's, its CAN traffic logged
    (``--can-log``) and its time series written as CSV and MDF4 (``--format both``)."""
    from ros_probe import Probe

    from damper_emulator.ros.launch import ros_environment

    bus = BusConfig(interface="udp_multicast", channel=udp_channel(OFFSETS["ride"]))
    probe = Probe(DOMAIN, "hybrid_probe")
    from diagnostic_msgs.msg import DiagnosticArray

    got: list = []
    probe.node.create_subscription(DiagnosticArray, "/diagnostics",
                                   lambda m: got.extend(m.status), 10)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            probe.executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    try:
        result = run_pair(tmp_path_factory.mktemp("ride"), bus, ["--corrupt-every", "100"],
                          ["--duration", "3", "--ros", "--learn", "--format", "both",
                           "--can-log", "{run}/ride.blf"],
                          env=ros_environment(DOMAIN))
    finally:
        stop.set()
        spinner.join(5)
        probe.close()
    return (*result, got)


#: The prototype's force r.m.s. over the test's class-C ride at 20 m/s (about 880 N,
#: tare included), for the live twin residual's bound [N].
FORCE_RMS_N = 850.0
#: A ride whose stall windows hold more than this share of it is the machine's, for the
#: bounds on its physics (each stall moves the car off its reference and the twin's input).
QUIET_SHARE = 0.1


def quiet_ride(doc: dict) -> bool:
    """Whether the ride's stalls leave its physics to be checked; otherwise a warning says
    that they were not (91 stalls in a 3 s ride once here: 7.6 % on sws_rms, twin residual
    149 N, while the tracking outside the stalls held its bound)."""
    share = doc["tracking"]["samples_in_stalls"] / doc["tracking"]["samples"]
    if share <= QUIET_SHARE:
        return True
    warnings.warn(f"the ride's physics unchecked: the machine stalled {doc['stalls']['count']} "
                  f"times, {share:.0%} of the ride in stall windows", stacklevel=2)
    return False


def test_compensated_ride_completes_and_tracks(ride):
    proc, out, _rig, _, _ = ride
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "hybrid.json").read_text())
    assert doc["status"] == "completed" and doc["reason"] == ""
    # the compensation's bound, outside the windows of the machine's stalls (a stall leaves
    # the rig on its last demand: 3.8 % over a whole ride once on this 2-core VM)
    tracked = doc["tracking"]
    assert tracked["nrms_outside_stalls"] < 0.03
    if doc["stalls"]["count"] == 0:
        assert tracked["nrms"] == pytest.approx(tracked["nrms_outside_stalls"], rel=1e-12)
    assert abs(doc["tracking"]["delay_ms"]) < 0.5
    if quiet_ride(doc):
        # the reference rides the learned twin, which misses the prototype's force by up
        # to 10 % (its friction's pre-sliding, its oil warmed by the characterisation):
        # 7 % on sws_rms once (with the twin the specimen, offline, 3 %: test_hybrid_core)
        for key, ratio in doc["ride_vs_reference"].items():
            assert abs(ratio) < 0.1, key
        rows = np.genfromtxt(out / "hybrid.csv", delimiter=",", names=True)
        force = rows["force_measured"][np.isfinite(rows["force_measured"])]
        assert doc["twin"]["residual_rms_n"] <= 0.1 * np.sqrt(np.mean(force ** 2))
        # the twin kept learning the warming prototype during the ride: by the end its
        # prediction misses by less than the twin as it came to the ride
        online = doc["twin"]["online"]
        assert online["enabled"] and online["updates"] > 0.9 * tracked["samples"]
        assert doc["twin"]["residual_rms_last_n"] < online["without"]["residual_rms_last_n"]
    assert doc["stability"]["force_path_gain"] < 1.0
    assert doc["stability"]["online"]["small_gain_margin"] > 1.0
    # the rig's identified transfer system: its 4 ms, rounded up to whole cycles, plus the
    # feedback's way back
    assert 4.0 < doc["transfer"]["delay_ms"] < 7.0
    assert doc["transfer"]["bandwidth_hz"] == pytest.approx(40.0, rel=0.1)
    assert doc["link"]["response_p50_us"] < 1000.0


def test_corrupted_frames_are_counted_and_the_ride_goes_on(ride):
    _proc, out, rig, _, _ = ride
    doc = json.loads((out / "hybrid.json").read_text())
    link = doc["link"]
    assert rig["corrupted"] > 50
    # the host dropped each corrupted feedback frame it received (the rig ran longer): one
    # in a hundred, and none besides, unless the rig's log witnesses a stall of the
    # machine: frames are lost on the way then, and a frame after a gap of 16 carries the
    # 4-bit counter of the last one accepted, which the host drops as not advanced
    received = link["feedback"] + link["dropped_checksum"]
    assert abs(link["dropped_checksum"] - received / 100) <= 2
    assert link["dropped_checksum"] > 30
    assert link["dropped"] == link["dropped_checksum"] or rig["stalls"], link
    assert doc["status"] == "completed"


def test_csv_and_bag_hold_the_ride(ride):
    _proc, out, _, _, _ = ride
    with open(out / "hybrid.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == CSV_COLUMNS
    data = np.array(rows[1:], dtype=float)
    doc = json.loads((out / "hybrid.json").read_text())
    assert data.shape[0] >= 3000
    assert np.all(np.diff(data[:, 0]) > 0)               # send times increase
    assert np.all(np.isin(data[:, 7], (0, 1)))
    assert np.nanmax(np.abs(data[:, 3])) <= SafetyParams().stroke_limit_m
    # an independent reader: rosbags
    from rosbags.highlevel import AnyReader

    with AnyReader([out / "bag"]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        force = [reader.deserialize(raw, c.msgtype).effort[0]
                 for c, _, raw in reader.messages(
                     [c for c in reader.connections if c.topic == "/damper/force"])]
        diags = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(
            [c for c in reader.connections if c.topic == "/diagnostics"])]
    assert counts["/damper/force"] == counts["/damper/state"] == counts["/hybrid/loop"] \
        == data.shape[0]
    assert np.allclose(force, data[:, 5], atol=1e-6, rtol=1e-9)
    keys = {kv.key for kv in diags[-1].status[0].values}
    assert {"twin_residual_rms_n", "tracking_nrms", "delay_ms"} <= keys
    assert abs(doc["tracking"]["samples"] - 3000) <= 1       # the evaluated 3 s
    for png in ("hybrid_tracking.png", "hybrid_force.png", "hybrid_transfer.png"):
        assert (out / png).stat().st_size > 10_000
    assert "Tracking" in (out / "report.md").read_text()


def test_the_rides_time_series_as_mdf4_are_the_csvs(ride):
    """``--format both``: hybrid.mf4 holds hybrid.csv's record, with units, comments and
    the conversions a measurement tool shows (raw ns as seconds, the enable as text), and
    ride_measured.mf4 reads back as ride_measured.csv does; read by asammdf."""
    from asammdf import MDF

    from damper_emulator.dyno.measured_bag import read_measured

    _proc, out, _, _, _ = ride
    data = np.loadtxt(out / "hybrid.csv", delimiter=",", skiprows=1)
    mdf = MDF(out / "hybrid.mf4")
    try:
        raw_ns = mdf.get("t_monotonic", raw=True)
        assert raw_ns.samples.dtype.kind == "i"
        assert np.array_equal(raw_ns.samples, data[:, 0].astype(np.int64))
        assert mdf.get("t_monotonic").unit == "s"
        assert np.allclose(mdf.get("t_monotonic").samples, data[:, 0] * 1e-9, rtol=1e-12)
        for i, name in enumerate(CSV_COLUMNS[2:7], start=2):
            signal = mdf.get(name)
            assert signal.unit == ("m" if name.startswith("stroke") else "N")
            assert signal.comment
            assert np.allclose(signal.samples, data[:, i], rtol=1e-8, atol=1e-12,
                               equal_nan=True), name
        assert np.allclose(mdf.get("force_measured").timestamps, data[:, 1], atol=1e-6)
        enable = mdf.get("enable")
        assert set(enable.samples.tolist()) <= {b"enabled", b"disabled"}
        assert np.array_equal(enable.samples == b"enabled", data[:, 7] == 1)
    finally:
        mdf.close()
    csv_data, mf4_data = (read_measured(out / f"ride_measured.{s}") for s in ("csv", "mf4"))
    for field in ("time", "displacement", "velocity", "force"):
        assert np.allclose(getattr(mf4_data, field), getattr(csv_data, field), rtol=1e-8,
                           atol=1e-12), field


def test_the_rides_can_log_holds_its_traffic_and_replays(ride, bus_db, tmp_path):
    """``--can-log``: every frame the link sent and received, as python-can's BLF reader
    reads it back, counted as the link counted them; ``replay`` takes the log (the
    measured stroke in, the measured force to compare with) and runs the learned twin
    against the damper on the rig, as the host did during the ride."""
    _proc, out, _, _, _ = ride
    doc = json.loads((out / "hybrid.json").read_text())
    link = doc["link"]
    log = out.parent / "ride.blf"
    frames = list(can.BLFReader(log))
    ids = {m.name: m.frame_id for m in bus_db.messages}
    sent = [f for f in frames if not f.is_rx]
    got = [f for f in frames if f.is_rx]
    assert {f.arbitration_id for f in sent} == {ids["DYNO_COMMAND"]}
    assert len(sent) == link["commands_sent"]
    assert len(got) == link["feedback"] + link["aux"] + link["dropped"]
    assert link["dropped"] >= 1                           # the rig's corrupted frames
    # the forces the log holds are those the run recorded as measured
    receiver = Receiver(bus_db, ["DYNO_FEEDBACK"])
    logged = [receiver.accept(f.arbitration_id, bytes(f.data)) for f in got
              if f.arbitration_id == ids["DYNO_FEEDBACK"]]
    forces = np.array([d.values["Force"] for d in logged if d is not None])
    assert forces.size == link["feedback"]
    measured = np.loadtxt(out / "hybrid.csv", delimiter=",", skiprows=1)[:, 5]
    assert np.isin(measured[np.isfinite(measured)], forces).all()
    replay = tmp_path / "replay"
    twin = out / "learn" / "twin_learned.yaml"
    r = subprocess.run([*CLI, "replay", str(log), "--out", str(replay), "--params",
                        str(twin)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    rep = json.loads((replay / "replay.json").read_text())
    assert rep["input"]["kind"] == "damper" and rep["trigger"] == "input"
    assert rep["compared"] == link["feedback"]
    assert rep["input"]["dropped"]["checksum"] == link["dropped_checksum"]
    # the learned twin against the damper, from the log, offline (the stroke's smoothed
    # derivative, the whole log) and as the host ran it beside the ride (the central
    # difference, the evaluated part, its online correction left out): one residual
    # (75.6 and 69.8 N r.m.s. here)
    online = doc["twin"]["online"]["without"]["residual_rms_n"]
    if quiet_ride(doc):
        assert rep["rms_N"] == pytest.approx(online, rel=0.3), (rep["rms_N"], online)


def test_feedback_cut_clears_enable_within_50_ms_and_exits_3(tmp_path, bus_db):
    """The rig stops its feedback: the host clears Enable within the watchdog's 50 ms, as
    the rig itself saw it (its last feedback sent, the first command with Enable clear
    received: a real-time process that reads every command), and keeps it clear.  (A tap
    of the bus in the test's process, under the suite's load, once lost frames past its
    socket's buffer: it saw 61 ms where the host had stopped at 41.)"""
    bus = BusConfig(interface="udp_multicast", channel=udp_channel(OFFSETS["cut"]))
    proc, out, rig_stats, tap = run_pair(tmp_path, bus, ["--feedback-stop-at", "3.0"],
                                         ["--duration", "3"], tap=True)
    assert proc.returncode == 3, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("damper-hil: stopped: no valid DYNO_FEEDBACK"), last
    doc = json.loads((out / "hybrid.json").read_text())
    assert doc["status"] == "stopped" and "DYNO_FEEDBACK" in doc["reason"]
    assert rig_stats["enable_cleared_ns"] is not None, \
        "no command with Enable clear after the feedback stopped"
    assert rig_stats["enable_cleared_ns"] - rig_stats["last_feedback_ns"] <= 50e6
    # and once the host cleared Enable after the rig's last feedback, every command keeps
    # it clear (of those the tap saw, in the order it saw them: each process turns the
    # kernel's stamps to its monotonic clock by an offset of its own, and the one or two
    # commands before the host exits were once stamped earlier by the tap than by the rig)
    ids = {bus_db.get_message_by_name(m).frame_id: m
           for m in ("DYNO_COMMAND", "DYNO_FEEDBACK")}
    rx = Receiver(bus_db, ["DYNO_COMMAND"])
    seen = [(ids[i], d) for _, i, d in tap.frames if i in ids]
    last_feedback = max(k for k, (name, _) in enumerate(seen) if name == "DYNO_FEEDBACK")
    enable = [rx.decode_values("DYNO_COMMAND", d)["Enable"]
              for name, d in seen[last_feedback:] if name == "DYNO_COMMAND"]
    assert 0 in enable, "the tap saw no command clear Enable after the last feedback"
    assert not any(enable[enable.index(0):])


@dataclasses.dataclass
class HeldRun:
    """A ``hybrid`` run whose process was held (SIGSTOP) once (:func:`held_run`)."""

    proc: subprocess.Popen
    before: str                 # its standard error before the hold
    rest: str                   # its standard error after the hold
    held_ms: float              # how long the process was held, as the test measured it
    out: Path
    rig_stats: dict
    host_stalls: list           # the sentinels' witnessed stalls of the machine
    tap: BusTap


def held_run(tmp: Path, offset: int, duration_s: float, held_in: str, after_s: float
             ) -> HeldRun:
    """``virtual-rig`` and ``hybrid`` on a private bus, with the machine's sentinels and a
    tap of the bus; the hybrid process is held for 200 ms ``after_s`` after it says
    ``hybrid: {held_in}``, then run to its end."""
    import signal
    import time

    bus = BusConfig(interface="udp_multicast", channel=udp_channel(offset))
    bus_args = ["--can-interface", bus.interface, "--can-channel", bus.channel]
    tmp.mkdir(parents=True, exist_ok=True)
    config = tmp / "short.yaml"
    config.write_text(SHORT)
    rig_json = tmp / "rig.json"
    sentinels = Sentinels(tmp)
    rig = start_rig([*bus_args, "--config", str(config), "--json", str(rig_json)])
    tap = BusTap(bus)
    out = tmp / "out"
    try:
        proc = subprocess.Popen([*CLI, "hybrid", "--out", str(out), "--config", str(config),
                                 *bus_args, "--duration", f"{duration_s:g}"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        assert proc.stderr is not None
        seen = []
        for line in proc.stderr:
            seen.append(line)
            if line.startswith(f"hybrid: {held_in}"):
                break
        else:
            raise AssertionError(f"the run never reached {held_in}: {''.join(seen)}")
        time.sleep(after_s)
        stopped = time.monotonic()
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(0.2)
        os.kill(proc.pid, signal.SIGCONT)
        # as long as it really was: a VM that halts the test too makes it longer (1.5 s once
        # in a clean clone's run here)
        held_ms = (time.monotonic() - stopped) * 1e3
        rest = proc.stderr.read()
        proc.wait(120)
    finally:
        rig.send_signal(2)
        rig.wait(timeout=20)
        tap.close()
        sentinels.close()
    rig_stats = read_rig_stats(rig_json)
    return HeldRun(proc, "".join(seen), rest, held_ms, out, rig_stats, sentinels.stalls,
                   tap)


def test_a_stall_of_the_host_past_the_watchdog_stops_the_run_with_enable_clear(tmp_path,
                                                                                bus_db):
    """The hybrid process held (SIGSTOP) for 200 ms in the ride.  The feedback that waited
    is stamped on arrival and looks fresh, but the host sent nothing for 200 ms (the rig,
    without commands, held): the run stops naming the host's stall, and every command
    computed after the stall has Enable clear."""
    run = held_run(tmp_path, OFFSETS["hoststall"], 3.0, "ride", 0.5)
    assert run.proc.returncode == 3, run.rest
    last = run.rest.strip().splitlines()[-1]
    assert last.startswith("damper-hil: stopped: the host stalled: no DYNO_COMMAND for"), last
    doc = json.loads((run.out / "hybrid.json").read_text())
    assert doc["status"] == "stopped" and doc["reason"].startswith("the host stalled")
    message = bus_db.get_message_by_name("DYNO_COMMAND")
    rx = Receiver(bus_db, ["DYNO_COMMAND"])
    decoded = [(t, rx.decode_values(i, d)) for t, i, d in run.tap.frames
               if i == message.frame_id]
    commands = [(t, v["Enable"]) for t, v in decoded]
    times = np.array([t for t, _ in commands])
    gap = int(np.argmax(np.diff(times)))
    # the stall, seen on the bus: past the watchdog, no longer than the process was held
    # (and the next cycle's wait), and as long as the run says it was (SIGSTOP takes hold
    # when the kernel next runs the process: the gap is not the test's 200 ms to the
    # millisecond; 105 ms once on a loaded machine)
    said_ms = float(re.search(r"no DYNO_COMMAND for (\d+) ms", last).group(1))
    seen_ms = (times[gap + 1] - times[gap]) * 1e3
    assert SafetyParams().watchdog_s * 1e3 < seen_ms < run.held_ms + 300
    assert seen_ms == pytest.approx(said_ms, abs=5)
    assert all(enable for _, enable in commands[gap - 100: gap + 1])   # riding before it
    # every command computed after the stall clears Enable.  A stall that lands between the
    # host's last look at its clock and the send lets the command computed before it out
    # late, once: the demand the rig held at (within a cycle's step), then Enable clear
    first = gap + 1
    if commands[first][1]:
        step = SafetyParams().velocity_limit_m_s / RigParams().rate_hz \
            + message.get_signal_by_name("StrokeDemand").scale
        held = decoded[gap][1]["StrokeDemand"]
        assert decoded[first][1]["StrokeDemand"] == pytest.approx(held, abs=step)
        first += 1
    assert not any(enable for _, enable in commands[first:])


def test_a_stall_of_the_host_before_the_ride_starts_it_again(tmp_path):
    """The hybrid process held (SIGSTOP) for 200 ms in the transfer identification: the
    host's own watchdog stops it; before the ride nothing is lost, so it clears Enable,
    connects again and starts over, saying why, and the ride completes (exit 0) with the
    restart in hybrid.json.  A run that a stall of the machine (a witness saw it) stopped
    later runs again.  In the ride every stop is final: one that the host's timing made
    there (a loaded machine's) is the ride's outcome, not the restart's, and is let pass
    with a warning."""
    for attempt in range(1, RUNS_THROUGH_STALLS + 1):
        run = held_run(tmp_path / f"run{attempt}", OFFSETS["restart"], 2.0, "identify", 0.4)
        why = machine_stalled(run.proc, run.out, run.rig_stats, run.host_stalls)
        if why is None and "starting again" in run.before:
            # the machine's timing stopped it before the test held it: the hold then
            # makes restart 2 of 2, not the restart this test is about
            why = "restarted before the hold: " + run.before.split("starting again")[0][-200:]
        if why is None:
            break
        warnings.warn(f"run {attempt} stopped by a stall of the machine: {why}", stacklevel=1)
    # in the identification (1.5 s), or its fit on a slow machine: both before the ride
    assert re.search(r"hybrid: stopped in (identify|fit) \(the host stalled", run.rest), \
        run.rest
    assert "starting again, restart 1 of 2" in run.rest, run.rest
    after = run.rest.split("starting again, restart 1 of 2", 1)[1]
    assert "hybrid: ride" in after, run.rest          # the restart reached the ride
    doc = json.loads((run.out / "hybrid.json").read_text())
    # one restart: a later timing stop before the ride would have been a second; in the
    # ride, a stop for the host's timing or at a limit the rig hit chasing the demand
    # after the host paused
    timing = re.match(r"(the host stalled|no valid DYNO_FEEDBACK)", doc["reason"])
    paused = None if timing else host_paused_before_the_stop(run.out)
    if run.proc.returncode == 3 and "starting again" not in after and (timing or paused):
        warnings.warn(f"the ride after the restart stopped: {doc['reason']}"
                      + (f" (the host had paused for {paused:.0f} ms)" if paused else ""),
                      stacklevel=1)
    else:
        assert run.proc.returncode == 0 and doc["status"] == "completed", run.rest
    restart, *more = doc["identification"]["restarts"]
    assert restart["phase"] in ("identify", "fit")
    assert restart["reason"].startswith("the host stalled")
    # a second restart only where a witness saw the machine stall (the restart's own
    # stale frames once caused one)
    assert not more or run.host_stalls or run.rig_stats.get("stalls"), more


def test_unstable_setting_is_stopped_before_any_limit(tmp_path):
    bus = BusConfig(interface="udp_multicast", channel=udp_channel(OFFSETS["unstable"]))
    proc, out, _, _ = run_pair(tmp_path, bus, ["--delay-ms", "30"],
                               ["--duration", "3", "--compensation", "none"])
    assert proc.returncode == 3, proc.stderr
    doc = json.loads((out / "hybrid.json").read_text())
    assert "unstable" in doc["reason"]
    data = np.genfromtxt(out / "hybrid.csv", delimiter=",", skip_header=1)
    limits = SafetyParams()
    assert np.nanmax(np.abs(data[:, 4])) < limits.stroke_limit_m
    assert np.nanmax(np.abs(data[:, 5])) < limits.force_limit_n
    assert np.nanmax(np.abs(data[:, 3])) <= limits.stroke_limit_m


def test_the_rigs_faults_wait_for_a_host_and_its_feedback_does_not():
    """Before the first valid command, a virtual rig with a delay change and a feedback
    stop due at once sends its feedback at its first delay: the faults' clock starts
    when a host takes the rig (a real bus, no host on it)."""
    from can_bridge.virtual_rig import RigFaults, run_virtual_rig
    from ride_sim.hybrid.params import ActuatorParams
    from ride_sim.hybrid.rig import VirtualRig

    bus = BusConfig(interface="udp_multicast", channel=udp_channel(OFFSETS["faults"]))
    rig = VirtualRig(DamperModel.from_file("config/sport.yaml"), ActuatorParams(),
                     RigParams())
    delay = rig.delay.delay_s
    stop = threading.Event()
    timer = threading.Timer(0.5, stop.set)
    timer.start()
    stats = run_virtual_rig(bus, load_database(required=HYBRID_SIGNALS), rig, stop,
                            faults=RigFaults(delay_change_at_s=0.0, delay_change_to_s=0.02,
                                             feedback_stop_at_s=0.0))
    timer.join()
    assert stats.commands == 0 and stats.cycles > 100
    assert stats.feedback_sent == stats.cycles
    assert rig.delay.delay_s == delay and stats.delay_changed_ns is None


@pytest.mark.parametrize("learn", [[], ["--learn"]])
def test_no_dyno_is_one_line_and_exit_2_before_anything_is_built(tmp_path, learn):
    """No dyno on the bus: one line, status 2, before the host or a characterisation is
    built and before the output directory is made."""
    config = tmp_path / "short.yaml"
    config.write_text(SHORT)
    proc = subprocess.run([*CLI, "hybrid", "--out", str(tmp_path / "out"), "--config",
                           str(config), "--can-interface", "udp_multicast",
                           "--can-channel", udp_channel(OFFSETS["nodyno"]),
                           "--duration", "2", *learn], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("damper-hil: error: no DYNO_FEEDBACK within 3 s on "
                           "udp_multicast"), last
    assert "Traceback" not in proc.stderr
    assert "hybrid: " not in proc.stderr          # no phase of a run began
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("args", "says"), [
    (["--duration", "-1"], "--duration"),
    (["--road-class", "Z"], "--road-class"),
    (["--can-interface", "nope"], "not a python-can interface"),
])
def test_bad_options_are_one_line_and_exit_2(cli, tmp_path, args, says):
    r = cli("hybrid", "--out", tmp_path / "out", "--can-interface", "udp_multicast",
            "--can-channel", "[ff11::d6:ff]:17999", *args)
    assert r.returncode == 2
    assert says in r.stderr and "Traceback" not in r.stderr


@pytest.mark.skipif(socketcan_problem("vcan0") is not None,
                    reason=str(socketcan_problem("vcan0")))
def test_the_ride_over_socketcan(tmp_path):
    bus = BusConfig(interface="socketcan", channel="vcan0")
    proc, out, _, _ = run_pair(tmp_path, bus, [], ["--duration", "2"])
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "hybrid.json").read_text())
    assert doc["tracking"]["nrms"] < 0.03
    assert math.isfinite(doc["twin"]["residual_rms_n"])


#: the share of a dyno run's samples left without a measurement up to which its recorded
#: force is checked against the model (the rig's own stalls, on a busy machine, leave it
#: off the history, 6-8 % off the model on it at 8-17 % of the cycles without feedback)
QUIET_LINK_SHARE = 0.05
#: the dyno test's faults: every 10th feedback frame a cycle late, every 50th corrupted
LATE_EVERY, CORRUPT_EVERY = 10, 50


def dyno_stalled(proc, out: Path, host_stalls) -> str | None:
    """Why a stopped ``dyno`` run says nothing about the code, or None: stalls left its
    identification too little (the host's account), or it stopped for a pause of the
    feedback or of its own loop while a sentinel at real-time priority woke late by as
    long (its JSON has no stop time to match them by)."""
    if (stop := _stopped(proc, out / "dyno.json")) is None:
        return None
    _, reason, pause_ms = stop
    if "from stalls" in reason:
        return reason
    if pause_ms is None:
        return None
    return _sentinel_late_by(reason, pause_ms, host_stalls)


#: the recorded force's r.m.s. off the rig's specimen on the recorded motion, relative,
#: up to which each sample's stroke and force are one cycle's
ON_MOTION_BOUND = 0.02
#: the rig's settling at the start of a record, left out of that comparison [s]
SETTLE_S = 0.05


def relative_rms(force: np.ndarray, reference: np.ndarray) -> float:
    return float(np.sqrt(np.mean((force - reference) ** 2) / np.mean(reference ** 2)))


def off_model_on_its_motion(measured) -> float:
    """The recorded force off the rig's specimen (the sport prototype) simulated on the
    recorded motion, past :data:`SETTLE_S` (:func:`relative_rms`)."""
    from damper_emulator.model.compressible import simulate
    from damper_emulator.params import PROTOTYPE_FILE, load_config

    specimen = DamperModel(load_config(PROTOTYPE_FILE))
    on_motion = simulate(specimen, measured.time, measured.displacement,
                         measured.velocity).force_n
    settled = measured.time >= SETTLE_S
    return relative_rms(measured.force[settled], on_motion[settled])


#: the recorded force's r.m.s. off the rig's specimen on the protocol's history (the
#: stroke demanded, not the one measured), relative: the rig's tracking too (1-2 % quiet)
ON_HISTORY_BOUND = 0.1


def stall_moved_the_rig(measured, stalls, on_history: float) -> str | None:
    """Why ``measured``, the record of a completed ``dyno`` run, says nothing about the
    code, or None: a sentinel saw the machine stall, or the virtual rig fell behind its cycle,
    during the run, and the recorded force is off the specimen on the recorded motion, or
    ``on_history`` (the force off the specimen on the protocol's history) is past
    :data:`ON_HISTORY_BOUND`.  The virtual rig's servo and specimen (a process of the
    test's, not the code under test) catch up a stall in one step: the stroke jumps, far
    past the sine's peak velocity, through samples the record cannot hold, and the force
    after it follows a motion the file does not show, or one off the protocol's."""
    if not stalls:
        return None
    off = off_model_on_its_motion(measured)
    if off < ON_MOTION_BOUND and on_history < ON_HISTORY_BOUND:
        return None
    late = max(ms for _, ms in stalls)
    return (f"the recorded force {100 * off:.1f} % off the specimen on the recorded "
            f"motion, {100 * on_history:.1f} % on the protocol's; a stall of {late:.0f} ms")


def _sentinel_late_by(reason: str, pause_ms: float, host_stalls) -> str | None:
    """``reason`` with the witness, when a sentinel woke late by as long as the pause
    that stopped a run (most of it), else None."""
    late = max((ms for _, ms in host_stalls), default=0.0)
    if late >= pause_ms - HOST_JITTER_MS:
        return f"{reason}; a sentinel woke late by {late:.0f} ms"
    return None


def test_dyno_protocol_on_the_rig_writes_measured_data(tmp_path):
    """``damper-hil dyno`` on the virtual rig, whose every 10th feedback frame comes a cycle
    late and every 50th is corrupted: the sine's CSV records what the rig measured, each
    stroke with the force of its own cycle (a late frame put in its place, a lost one's
    sample left out), which is the specimen's force on the protocol (the offline model's
    of the rig's specimen, the sport prototype, to the rig's noise and tracking).  A run
    that the machine stopped (:func:`dyno_stalled`), or whose record a stall of the machine
    moved (:func:`stall_moved_the_rig`), runs again, with a warning."""
    from damper_emulator.dyno.measured import read_measured_csv
    from damper_emulator.dyno.runner import run_sine
    from damper_emulator.params import PROTOTYPE_FILE, load_config

    ch = udp_channel(OFFSETS["dyno"])
    bus_args = ["--can-interface", "udp_multicast", "--can-channel", ch]
    config = tmp_path / "short.yaml"
    config.write_text(SHORT)
    specimen = DamperModel(load_config(PROTOTYPE_FILE))      # the rig's
    run_sine(specimen, tmp_path / "model", 2.0, 0.02, cycles=2)
    model = read_measured_csv(tmp_path / "model" / "sine_2hz.csv")

    def off_the_history(measured) -> tuple[float, np.ndarray]:
        kept = np.searchsorted(model.time, measured.time)
        return relative_rms(measured.force, model.force[kept]), kept

    for attempt in range(1, RUNS_THROUGH_STALLS + 1):
        out = tmp_path / f"rig{attempt}"
        out.mkdir()
        rig = start_rig([*bus_args, "--config", str(config), "--late-every",
                         str(LATE_EVERY), "--corrupt-every", str(CORRUPT_EVERY),
                         "--json", str(out / "rig.json")])
        sentinels = Sentinels(out)
        try:
            proc = subprocess.run([*CLI, "dyno", "--protocol", "sine", "--frequency", "2",
                                   "--amplitude", "0.02", "--cycles", "2", "--out", str(out),
                                   "--rig-config", str(config), *bus_args,
                                   "--can-log", str(out / "rig.asc")],
                                  capture_output=True, text=True, timeout=300)
        finally:
            sentinels.close()
            rig.send_signal(2)
            rig.wait(timeout=20)
        stalls = sentinels.stalls + read_rig_stats(out / "rig.json").get("stalls", [])
        why = dyno_stalled(proc, out, sentinels.stalls)
        if why is None and proc.returncode == 0:
            measured = read_measured_csv(out / "sine_2hz.csv")
            why = stall_moved_the_rig(measured, stalls, off_the_history(measured)[0])
        if why is None:
            break
        warnings.warn(f"run {attempt} disturbed by a stall of the machine: {why}",
                      stacklevel=1)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "dyno.json").read_text())
    run = doc["rig"]["runs"][0]
    assert run["phase_at_end"] == "done" and run["tracking_nrms"] < 0.03
    # --can-log: the run's traffic, as python-can's reader reads it back
    frames = list(can.ASCReader(out / "rig.asc"))
    assert sum(not f.is_rx for f in frames) == run["link"]["commands_sent"]
    assert sum(f.is_rx for f in frames) == (run["link"]["feedback"] + run["link"]["aux"]
                                            + run["link"]["dropped"])
    measured = read_measured_csv(out / "sine_2hz.csv")
    on_history, kept = off_the_history(measured)
    # the late frames were put in their cycles; a sample whose frame never came (a
    # corrupted one, one a stall of the machine cost) is left out of the file
    link, missing = run["link"], run["samples_without_measurement"]
    assert link["late_feedback"] >= run["samples_measured_late"] >= 0.5 * run["samples"] \
        / LATE_EVERY
    assert missing >= 0.5 * run["samples"] / CORRUPT_EVERY
    assert np.allclose(model.time[kept], measured.time, rtol=0, atol=1e-9)
    assert 0 < model.time.size - measured.time.size <= missing + 2
    # the displacement is the rig's measurement, not the demand: close to it, not equal,
    # to the tracking bound above (in r.m.s.: a stall of the host moves a few samples, and
    # the peak is the stall's; 1.17 mm once in a clean clone's make test)
    assert 0 < relative_rms(measured.displacement, model.displacement[kept]) < 0.03

    # each sample's stroke and force are one cycle's: the model on the measured motion
    # gives the measured force (0.5 % here; a sample held from an earlier cycle, as before
    # the late frames were placed, made it 3.9 %)
    consistent = off_model_on_its_motion(measured)
    if missing <= QUIET_LINK_SHARE * run["samples"]:
        assert consistent < ON_MOTION_BOUND
        # on the protocol's history: the rig's tracking too, which the machine's stalls
        # disturb (6.5 % once, the machine stalling a third of the cycles then; 13 % once,
        # the record itself under 2 % off on its motion)
        assert on_history < ON_HISTORY_BOUND
    else:
        warnings.warn(f"the recorded force unchecked ({100 * consistent:.1f} % off the model "
                      f"on the measured motion, {100 * on_history:.1f} % on the history): "
                      f"{missing} samples without a measurement", stacklevel=1)


def test_the_twin_learns_the_specimen_on_the_rig(ride):
    """The ride's ``--learn``, against the virtual rig's default specimen, the sport
    prototype, which is not the sport twin (other valves, a stiffer oil, a LuGre friction,
    an oil that thins as it warms): the characterisation's files are the rig's, the twin
    learned from them misses them far less than the sport twin did, its file loads, and the
    ride used it (its residual over the ride: test_compensated_ride_completes_and_tracks)."""
    from damper_emulator.params import load_config

    proc, out, *_ = ride
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "hybrid.json").read_text())
    learned = doc["twin_learning"]
    before, after = learned["residual_before"], learned["residual_after"]
    assert before["chirp.csv"]["relative_rms"] >= 0.2          # the twin was not the specimen
    assert after["chirp.csv"]["rms_n"] < 0.25 * before["chirp.csv"]["rms_n"]
    # the quasi-static test's reversals: the LuGre friction's pre-sliding, which the paper's
    # Coulomb friction cannot follow (35 -> 31 N here; where the rig reverses faster, as
    # offline, 26 -> 6 N)
    assert after["quasi_static.csv"]["rms_n"] < before["quasi_static.csv"]["rms_n"]
    assert (out / "learn" / "chirp.csv").exists()
    assert "| chirp.csv |" in (out / "report.md").read_text()
    assert doc["settings"]["twin"] == learned["params_file"]
    DamperModel(load_config(learned["params_file"]))


def test_the_twin_residual_is_live_on_diagnostics(ride):
    from ride_sim.hybrid.recorder import DIAGNOSTIC_NAME

    _proc, out, *_, got = ride
    ours = [st for st in got if st.name == DIAGNOSTIC_NAME]
    assert len(ours) >= 3                       # once a second over a 3 s ride and more
    values = {kv.key: kv.value for kv in ours[-1].values}
    assert math.isfinite(float(values["twin_residual_rms_n"]))
    if quiet_ride(json.loads((out / "hybrid.json").read_text())):
        assert float(values["twin_residual_rms_n"]) < 0.1 * FORCE_RMS_N
        assert float(values["tracking_nrms"]) < 0.05
    assert 4.0 < float(values["delay_ms"]) < 7.0
