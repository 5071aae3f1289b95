"""CAN traffic logged as BLF and ASC (``--can-log``, the bridge's ``can_log``), read back
by python-can's own readers, and CAN logs replayed (``damper-hil replay run.blf``).

The replayed logs are written here with python-can's writers from frames encoded through
the CAN database, their forces computed by the model's batch simulation on the decoded
(quantised) inputs: the replay must give them back to the force's resolution.  The log
of a real ride (``hybrid --can-log``) is replayed in tests/test_hybrid_can.py.
"""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest

from can_bridge.bus import BusConfig, ResilientBus
from can_bridge.can_log import CanLog, CanLogError, check_log_path
from can_bridge.codec import Encoder
from can_bridge.dbc import load_database
from can_bridge.log_input import read_can_log
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config
from damper_emulator.replay import load_emulator_params, run_replay
from damper_emulator.replay_emulation import emulate, run_model

pytestmark = pytest.mark.can

CLI = [sys.executable, "-m", "damper_hil.cli"]
#: DAMPER_FORCE's resolution [N] (config/damper.dbc): the most a replay may differ by,
#: half of it, plus the float rounding of the time steps
FORCE_STEP_N = 0.5


@pytest.fixture(scope="module")
def db():
    return load_database()


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_every_frame_sent_and_received_is_in_the_log(tmp_path, suffix):
    """Two buses on one virtual channel: what the logged bus sends and receives is in the
    file, in order, marked Tx/Rx, with its data and a time stamp of when it passed; read
    back by python-can's reader."""
    channel = f"log-{suffix[1:]}-{time.monotonic_ns()}"
    path = tmp_path / f"run{suffix}"
    log = CanLog(path)
    sent, received = [], []
    with ResilientBus(BusConfig(interface="virtual", channel=channel), log=log) as ours, \
            ResilientBus(BusConfig(interface="virtual", channel=channel)) as theirs:
        assert ours.ensure_open() and theirs.ensure_open()
        before = time.time()
        for i in range(40):
            frame = can.Message(arbitration_id=0x100 + i % 3, data=bytes([i, 255 - i, 7]),
                                is_extended_id=False)
            assert ours.send(frame)
            sent.append(frame)
            reply = can.Message(arbitration_id=0x1F0, data=bytes([i] * 8),
                                is_extended_id=False)
            assert theirs.send(reply)
            got = ours.recv(1.0)
            assert got is not None
            received.append(got)
    log.close()
    log.close()                                          # idempotent
    after = time.time()
    assert log.frames == 80 and log.error is None
    # (the ASC reader's times count from the file's start unless asked for the wall clock)
    frames = list(can.ASCReader(path, relative_timestamp=False) if suffix == ".asc"
                  else can.BLFReader(path))
    assert len(frames) == 80
    assert [f.is_rx for f in frames] == [False, True] * 40
    expect = [m for pair in zip(sent, received) for m in pair]
    for got, want in zip(frames, expect):
        assert got.arbitration_id == want.arbitration_id
        assert bytes(got.data) == bytes(want.data)
    stamps = np.array([f.timestamp for f in frames])
    assert before - 1e-3 <= stamps.min() and stamps.max() <= after + 1e-3
    assert np.all(np.diff(stamps) >= -1e-6)


@pytest.mark.parametrize("ms", [0, 7, 10, 99, 100, 999])
def test_an_asc_logs_start_is_read_back_to_the_millisecond(tmp_path, ms):
    """An ASC file's frames count from its start, written as a date with milliseconds;
    a start 10 ms into its second written ``.10`` would read back 90 ms late (python-can
    4.6.1's writer did so: one start in ten)."""
    path = tmp_path / "start.asc"
    log = CanLog(path)
    stamp = math.floor(time.time()) + ms / 1000.0         # within the log's tolerance
    log.add(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False,
                        timestamp=stamp), received=True)
    log.close()
    (frame,) = can.ASCReader(path, relative_timestamp=False)
    assert frame.timestamp == pytest.approx(stamp, abs=1e-6 + 1e-3)


def test_a_log_path_that_would_lose_or_misname_a_recording_is_one_line(tmp_path):
    with pytest.raises(CanLogError, match=r"\.blf \(Vector binary\) or \.asc"):
        check_log_path(tmp_path / "run.txt")
    existing = tmp_path / "run.blf"
    existing.write_bytes(b"old")
    with pytest.raises(CanLogError, match="never overwrites a recording"):
        CanLog(existing)
    assert existing.read_bytes() == b"old"
    for args in (["virtual-rig", "--can-log", str(tmp_path / "x.log"), "--duration", "1"],
                 ["hybrid", "--out", str(tmp_path / "o"), "--can-log", str(existing)],
                 ["bridge", "--can-log", str(existing)]):
        r = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2, (args, r.stderr)
        assert "Traceback" not in r.stderr and "--can-log" in r.stderr, r.stderr


def _sine(n: int = 1500, rate_hz: float = 1000.0) -> tuple[np.ndarray, np.ndarray,
                                                             np.ndarray]:
    t = np.arange(n) / rate_hz
    x = 0.03 * np.sin(2 * np.pi * 2.0 * t) + 0.005 * np.sin(2 * np.pi * 11.0 * t)
    v = np.gradient(x, t)
    return t, x, v


def _write_log(path: Path, frames: list[tuple[float, int, bytes, bool]]) -> None:
    """An independent writer: python-can's, by suffix."""
    with can.Logger(path) as writer:
        for stamp, frame_id, data, rx in sorted(frames, key=lambda f: f[0]):
            writer.on_message_received(can.Message(timestamp=stamp, arbitration_id=frame_id,
                                                   data=data, is_extended_id=False,
                                                   is_rx=rx))


def _emulator_log(db, path: Path, answer_every: int = 1, fault_frames: int = 0,
                  stall: tuple[int, float] | None = None):
    """A dyno's DAMPER_STATE frames and the emulator's DAMPER_FORCE answers (each 300 µs
    after its state; ``answer_every`` > 1 leaves states unanswered), the forces the model's
    on the decoded states.  ``stall``: the emulator stops at that state for that long [s],
    then answers the states that came meanwhile in a burst, 20 µs apart, until it has
    caught up.  Returns the forces sent [N]."""
    state_enc, force_enc = Encoder(db, "DAMPER_STATE"), Encoder(db, "DAMPER_FORCE")
    state_msg = db.get_message_by_name("DAMPER_STATE")
    t, x, v = _sine()
    t0 = 1.7e9
    frames, decoded = [], []
    for ti, xi, vi in zip(t, x, v):
        data, _ = state_enc.encode(Stroke=xi, Velocity=vi)
        frames.append((t0 + ti, state_enc.frame_id, bytes(data), True))
        values = state_msg.decode(bytes(data))
        decoded.append((values["Stroke"], values["Velocity"]))
    xq, vq = np.array(decoded).T
    # the model steps by the states' stamps as python-can reads them back (seconds since
    # the epoch in a float: to about 0.24 µs, which moves a force by up to some 3 N)
    _write_log(path, frames)
    stamps = np.array([m.timestamp for m in can.LogReader(path)])
    path.unlink()
    model = DamperModel(load_config(None))
    force = run_model(model, np.round(stamps * 1e9).astype(np.int64), xq, vq)[0]
    sent = []
    busy_until = -np.inf
    for i in range(0, t.size, answer_every):
        data, _ = force_enc.encode(Force=force[i], Status=0, InputAge=0.0,
                                   StrokeUsed=xq[i])
        if stall is not None and i == stall[0]:
            busy_until = t[i] + stall[1]
        busy_until = max(t[i] + 3e-4, busy_until + 2e-5)
        frames.append((t0 + busy_until, force_enc.frame_id, bytes(data), False))
        sent.append(force[i])
    for k in range(fault_frames):     # the bridge's own: no force from the emulator
        data, _ = force_enc.encode(Force=0.0, Status=32, InputAge=0.0, StrokeUsed=0.0)
        frames.append((t0 + t[-1] + 0.02 * (k + 1), force_enc.frame_id, bytes(data), False))
    _write_log(path, frames)
    return np.array(sent)


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_a_dyno_and_emulator_log_replays_to_the_forces_resolution(db, tmp_path, suffix):
    """Every state answered by its own force: the replay runs ``input``, one force per
    state at its stamp, and gives the logged forces back within half their resolution;
    the bridge's fault frames are counted, not compared."""
    log = tmp_path / f"dyno{suffix}"
    sent = _emulator_log(db, log, fault_frames=3)
    doc = run_replay(log, tmp_path / "out", plot=False,
                     reader=lambda p: read_can_log(p))
    assert doc["trigger"] == "input"
    assert doc["input"]["kind"] == "emulator" and doc["input"]["bridge_fault_frames"] == 3
    assert doc["input"]["outputs_answer_their_inputs"] is True
    assert doc["compared"] == sent.size == doc["state_messages"]
    assert doc["max_abs_N"] <= FORCE_STEP_N / 2 + 1e-6
    assert doc["recorded_rms_N"] == pytest.approx(np.sqrt(np.mean(sent ** 2)), abs=0.3)
    # the output bag holds the states and the replayed forces: an independent reader
    from rosbags.highlevel import AnyReader

    with AnyReader([tmp_path / "out" / "replay_bag"]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts == {"/damper/state": sent.size, "/damper/force": sent.size}


def test_an_emulator_that_stalled_still_answers_one_for_one(db, tmp_path):
    """An emulator triggered by its input that stalled for 40 ms (a host's hiccup) answers
    the 40 states that came meanwhile in a burst, the last of them long after the next
    states came: still each state answered by its own force, in turn, so the replay runs
    ``input`` and gives the logged forces back."""
    log = tmp_path / "stalled.asc"
    sent = _emulator_log(db, log, stall=(700, 0.04))
    doc = run_replay(log, tmp_path / "out", plot=False, reader=lambda p: read_can_log(p))
    assert doc["trigger"] == "input" and doc["input"]["outputs_answer_their_inputs"] is True
    assert doc["compared"] == sent.size == doc["state_messages"]
    assert doc["max_abs_N"] <= FORCE_STEP_N / 2 + 1e-6


def test_a_timer_emulators_log_replays_tick_by_tick(db, tmp_path):
    """Forces that do not answer each state one for one (every third here): the replay
    runs ``timer``, a tick per logged force, its input found by ``StrokeUsed``."""
    log = tmp_path / "timer.blf"
    sent = _emulator_log(db, log, answer_every=3)
    doc = run_replay(log, tmp_path / "out", plot=False, reader=lambda p: read_can_log(p))
    assert doc["trigger"] == "timer" and doc["input"]["outputs_answer_their_inputs"] is False
    assert doc["compared"] == sent.size
    # the model steps three samples at a time here, where the forces were computed at
    # every sample: a step three times as long, a little further from the exact solution
    assert doc["relative_rms"] < 0.02


def test_a_log_without_frames_to_replay_and_a_damaged_one_are_one_line(db, tmp_path):
    empty = tmp_path / "other.blf"
    _write_log(empty, [(1.0 + i * 1e-3, 0x7FF, bytes(8), True) for i in range(10)])
    r = subprocess.run([*CLI, "replay", str(empty), "--out", str(tmp_path / "o1")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "no DAMPER_STATE with DAMPER_FORCE frames, nor DYNO_FEEDBACK" in r.stderr
    damaged = tmp_path / "damaged.blf"
    _emulator_log(db, damaged)
    raw = damaged.read_bytes()
    damaged.write_bytes(raw[:200] + bytes(range(256)) * 8 + raw[2000:])
    r = subprocess.run([*CLI, "replay", str(damaged), "--out", str(tmp_path / "o2")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert str(damaged) in r.stderr and len(r.stderr.strip().splitlines()) <= 2, r.stderr
    assert not (tmp_path / "o2").exists()


def test_a_damper_logs_lost_frames_keep_their_cycles(db, tmp_path):
    """A physical damper's DYNO_FEEDBACK log with frames lost, once fewer and once more
    than the alive counter's 16: the frames stay on their cycles (the time between them
    tells whole counter turns) and the velocity is the stroke's derivative over cycles,
    not frames, so the model on the logged stroke gives the force it was made from,
    without the spike a gap would put in the velocity."""
    enc = Encoder(db, "DYNO_FEEDBACK")
    model = DamperModel(load_config(None))
    t = np.arange(3000) * 1e-3
    x = 0.02 * np.sin(2 * np.pi * 1.5 * t)
    v = 0.02 * 2 * np.pi * 1.5 * np.cos(2 * np.pi * 1.5 * t)
    force = run_model(model, np.round(t * 1e9).astype(np.int64), x, v)[0]
    lost = set(range(1000, 1006)) | set(range(2000, 2040))
    frames = []
    for i in range(t.size):
        data, _ = enc.encode(StrokeMeasured=x[i], Force=force[i], Status=0)
        if i not in lost:       # the counter counts on: the frame was sent, not received
            frames.append((1.7e9 + t[i] + 2e-5 * np.sin(i), enc.frame_id, bytes(data), True))
    log = tmp_path / "damper.blf"
    _write_log(log, frames)
    data, info = read_can_log(log)
    assert info["kind"] == "damper" and info["cycles_without_frame"] == len(lost)
    assert info["cycle_period_s"] == pytest.approx(1e-3, rel=1e-6)
    stamps = (data.state.stamp_ns - data.state.stamp_ns[0]) * 1e-9
    kept = np.array(sorted(set(range(t.size)) - lost))
    np.testing.assert_allclose(stamps, t[kept], atol=1e-6)
    # the stroke comes in 10 µm steps (a step inside the filter's 11 cycles is some 2 mm/s
    # of it): its smoothed derivative follows the true one to under 1 mm/s r.m.s., 3 mm/s
    # at most away from the 40-cycle gap, and 1 cm/s at its edges (the stroke inside it,
    # filled by a straight line, is not the sine's)
    error = np.abs(data.state.velocity[:, 0] - v[kept])
    near = (kept >= 2000 - 15) & (kept < 2040 + 15)
    assert np.sqrt(np.mean(error ** 2)) < 1e-3
    assert error[~near].max() < 3e-3 and error[near].max() < 1e-2
    doc = run_replay(log, tmp_path / "out", plot=False, reader=lambda p: read_can_log(p))
    assert doc["compared"] == kept.size and doc["relative_rms"] < 0.005, doc
    # the force the model gives on the logged stroke: where the velocity crosses zero the
    # damper's steepest slope turns the stroke's 10 µm steps into some 90 N; a gap adds
    # less than that (a 41 ms step of the model over the 40 lost cycles: 21 N), where a
    # derivative over frames had put a spike of hundreds of N after it
    replayed = emulate(data, model, load_emulator_params()[0]).force_n
    error = np.abs(replayed - force[kept])
    assert error.max() < 0.05 * np.abs(force).max()
    assert error[near].max() < 0.5 * error[~near].max()


def test_a_frame_stamped_on_an_interfaces_own_clock_is_logged_when_it_came(tmp_path):
    """Some interfaces stamp frames with their own clock (a device's time since its
    start): such a stamp is no time of the log's, and the frame takes the time it was
    logged, between its neighbours."""
    path = tmp_path / "clocks.blf"
    log = CanLog(path)
    before = time.time()
    for stamp in (before, 5.0, before + 0.5):        # the second from a device's clock
        log.add(can.Message(timestamp=stamp, arbitration_id=0x100, data=b"\x01"),
                received=True)
    log.close()
    stamps = [m.timestamp for m in can.BLFReader(path)]
    assert len(stamps) == 3 and stamps == sorted(stamps)
    assert stamps[0] == pytest.approx(before, abs=1e-6)
    assert before <= stamps[1] <= before + 0.5 <= stamps[2] + 1e-6
