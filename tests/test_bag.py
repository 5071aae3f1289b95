"""damper_emulator.bag: rosbag2/MCAP bags that survive SIGKILL.

Every bag is read back with two independent readers, rosbags' rosbag2
Reader and the ``mcap`` package's reader, on real files.
"""

import contextlib
import itertools
import json
import os
import signal
import struct
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.metadata import parse_qos
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.typesys import Stores, get_typestore

from damper_emulator.bag import (
    BagError,
    BagWriter,
    Qos,
    messages,
    open_bag,
    read_messages,
    topic_counts,
)
from damper_emulator.bag import writer as writer_mod

TS = get_typestore(Stores.ROS2_JAZZY)
MAGIC = b"\x89MCAP0\r\n"
JS, F64, DIAG = (
    "sensor_msgs/msg/JointState",
    "std_msgs/msg/Float64",
    "diagnostic_msgs/msg/DiagnosticArray",
)
T0 = 1_700_000_000_000_000_000
CHILD = Path(__file__).with_name("bag_kill_child.py")


# ----------------------------------------------------------------- helpers


def mcap_file(bag: Path) -> Path:
    (path,) = bag.glob("*.mcap")
    return path


def read_rosbags(bag: Path):
    """(topic, timestamp, decoded msg) and connections, with rosbags alone."""
    with Reader(bag) as reader:
        conns = list(reader.connections)
        msgs = [
            (conn.topic, ts, TS.deserialize_cdr(data, conn.msgtype))
            for conn, ts, data in reader.messages()
        ]
    return msgs, conns


def read_mcap(bag: Path):
    """(topic, log_time, data) with the mcap package (CRCs checked), channels, schemas, summary."""
    with open(mcap_file(bag), "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_header().profile == "ros2"
        out, channels, schemas = [], {}, {}
        for schema, channel, msg in reader.iter_messages(log_time_order=True):
            assert msg.publish_time == msg.log_time
            out.append((channel.topic, msg.log_time, bytes(msg.data)))
            channels[channel.topic] = channel
            schemas[channel.topic] = schema
        summary = reader.get_summary()
    return out, channels, schemas, summary


def walk_records(data: bytes):
    """Opcodes and lengths of the top-level records; the file must end right after the
    footer."""
    assert data[:8] == MAGIC and data[-8:] == MAGIC
    pos, ops = 8, []
    while True:
        op = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        ops.append((op, length))
        pos += 9 + length
        if op == 0x02:
            break
    assert pos + 8 == len(data), "bytes after the footer"
    return ops


def check_summary_crc(data: bytes) -> None:
    """The footer's summary CRC covers the summary section and the footer up to the CRC field."""
    footer = len(data) - 8 - 29
    summary_start, _, crc = struct.unpack_from("<QQI", data, footer + 9)
    assert summary_start and crc == zlib.crc32(data[summary_start : footer + 25])


def js_values(i):
    return [f"j{i % 3}", "k"], [i * 0.5, -1.0], [i * 0.25, 2.0], [float(i), 3.0]


def share_hash(msgtype):
    """RIHS01 hash from the type description JSON that rosidl installs with the message package."""
    from ament_index_python.packages import get_package_share_directory

    pkg, _, name = msgtype.split("/")
    path = Path(get_package_share_directory(pkg)) / "msg" / f"{name}.json"
    hashes = json.loads(path.read_text())["type_hashes"]
    return next(h["hash_string"] for h in hashes if h["type_name"] == msgtype)


# ---------------------------------------------------------------- messages


def test_msgdef_and_type_hash_match_the_installed_ros_descriptions():
    for msgtype in (JS, F64, DIAG):
        assert messages.type_hash(msgtype) == TS.hash_rihs01(msgtype)
        # pragma: no cover - ROS share files absent
        with contextlib.suppress(ImportError, LookupError, OSError):
            assert messages.type_hash(msgtype) == share_hash(msgtype)
        assert messages.msgdef(msgtype) == TS.generate_msgdef(msgtype, ros_version=2)[0]
    assert messages.msgdef(JS).startswith("std_msgs/Header header\nstring[] name\n")
    with pytest.raises(BagError, match="unknown message type"):
        messages.type_hash("nope_msgs/msg/Nope")


@pytest.mark.ros
def test_cdr_equals_rclpy():
    pytest.importorskip("rclpy")
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    assert messages.float64(-1.25) == bytes(serialize_message(Float64(data=-1.25)))

    stamp = 1_700_000_123_456_789_012
    names, pos, vel, eff = ["damper", "abc"], [0.0123, -4.5], [0.7, 1e-9], [1234.5, -0.5]
    ours = messages.joint_state(stamp, names, pos, vel, eff, frame_id="base")
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp, 10**9)
    m.header.frame_id = "base"
    m.name, m.position, m.velocity, m.effort = names, pos, vel, eff
    theirs = bytes(serialize_message(m))
    # Same length and the same bytes, except alignment padding, which rmw_fastrtps leaves
    # uninitialised (rosbags writes zeros): compare every byte rosbags did not write as 0.
    assert len(ours) == len(theirs)
    assert all(a == b for a, b in zip(ours, theirs) if a != 0)
    assert deserialize_message(ours, JointState) == m
    back = messages.deserialize(theirs, JS)
    assert back.header.stamp.sec * 10**9 + back.header.stamp.nanosec == stamp
    assert list(back.name) == names and back.effort.tolist() == eff

    # rclpy pads a JointState with empty float64 sequences to its estimated size: rosbags'
    # deserialize_cdr refuses that, ours accepts it.
    m.velocity, m.effort = [], []
    padded = bytes(serialize_message(m))
    assert len(padded) > len(messages.joint_state(stamp, names, pos, [], [], frame_id="base"))
    assert messages.deserialize(padded, JS).position.tolist() == pos


def test_message_helpers_round_trip():
    data = messages.diagnostic_array(T0, [(1, "damper", "hot", "hw0", [("temp", "81.5")])])
    msg = messages.deserialize(data, DIAG)
    assert msg.status[0].name == "damper" and msg.status[0].values[0].value == "81.5"
    assert messages.deserialize(messages.float64(2.5), F64).data == 2.5
    with pytest.raises(ValueError, match="stamp_ns -1 out of range"):
        messages.joint_state(-1, [], [], [], [])
    with pytest.raises(BagError):
        messages.deserialize(b"\x00\x01\x00\x00\x01", JS)


# --------------------------------------------------------------- round trip


def test_round_trip_three_topics(tmp_path):
    bag = tmp_path / "run"
    qos_js = Qos(reliability="reliable", durability="volatile", history="keep_last", depth=10)
    qos_f = Qos(
        reliability="best_effort",
        durability="transient_local",
        history="keep_last",
        depth=1,
        deadline_ns=1_500_000_000,
    )
    expected = {}
    with BagWriter(bag, flush_period_s=0.05, custom_data={"run": "unit", "model": "sport"}) as w:
        c_js = w.add_topic("/damper/state", JS, qos=qos_js)
        c_f = w.add_topic("/damper/force", F64, qos=qos_f)
        c_d = w.add_topic("/diagnostics", DIAG)
        for i in range(3000):
            t = T0 + i * 333_333
            names, pos, vel, eff = js_values(i)
            w.write(c_js, t, messages.joint_state(t, names, pos, vel, eff))
            expected.setdefault("/damper/state", []).append((t, i))
            w.write(c_f, t + 1, messages.float64(i * 0.1))
            expected.setdefault("/damper/force", []).append((t + 1, i))
            if i % 10 == 0:
                status = (i % 4, "damper", f"m{i}", "hw", [("i", str(i))])
                w.write(c_d, t + 2, messages.diagnostic_array(t + 2, [status]))
                expected.setdefault("/diagnostics", []).append((t + 2, i))
            if i % 700 == 0:
                w.flush()
    assert w.closed

    def check_value(topic, ts, msg, i):
        if topic == "/damper/state":
            names, pos, vel, eff = js_values(i)
            assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == ts
            assert list(msg.name) == names
            assert msg.position.tolist() == pos and msg.velocity.tolist() == vel
            assert msg.effort.tolist() == eff
        elif topic == "/damper/force":
            assert msg.data == i * 0.1
        else:
            assert msg.status[0].message == f"m{i}" and msg.status[0].level == i % 4

    # rosbags
    msgs, conns = read_rosbags(bag)
    assert len(msgs) == sum(len(v) for v in expected.values())
    assert [m[1] for m in msgs] == sorted(m[1] for m in msgs)
    for topic, exp in expected.items():
        got = [(ts, msg) for tp, ts, msg in msgs if tp == topic]
        assert [ts for ts, _ in got] == [ts for ts, _ in exp]
        for (ts, msg), (_, i) in zip(got, exp):
            check_value(topic, ts, msg, i)
    by_topic = {c.topic: c for c in conns}
    for topic, msgtype, qos in (
        ("/damper/state", JS, qos_js),
        ("/damper/force", F64, qos_f),
        ("/diagnostics", DIAG, Qos()),
    ):
        conn = by_topic[topic]
        assert conn.msgtype == msgtype
        assert conn.digest == TS.hash_rihs01(msgtype)
        assert conn.msgcount == len(expected[topic])
        assert [Qos.from_rosbags(q) for q in conn.ext.offered_qos_profiles] == [qos]
        assert conn.ext.serialization_format == "cdr"
    with Reader(bag) as reader:
        assert reader.message_count == len(msgs)
        assert reader.start_time == msgs[0][1] and reader.end_time == msgs[-1][1] + 1

    # mcap package (CRC-checked)
    raw, channels, schemas, summary = read_mcap(bag)
    assert [(tp, ts) for tp, ts, _ in raw] == [(tp, ts) for tp, ts, _ in msgs]
    assert summary is not None and summary.statistics.message_count == len(msgs)
    assert summary.statistics.metadata_count == 1 and summary.chunk_indexes
    for topic, msgtype, qos in (("/damper/state", JS, qos_js), ("/damper/force", F64, qos_f)):
        ch, sc = channels[topic], schemas[topic]
        assert ch.message_encoding == "cdr" and sc.encoding == "ros2msg" and sc.name == msgtype
        assert sc.data.decode() == TS.generate_msgdef(msgtype, ros_version=2)[0]
        assert ch.metadata["topic_type_hash"] == TS.hash_rihs01(msgtype)
        assert [Qos.from_rosbags(q) for q in parse_qos(ch.metadata["offered_qos_profiles"])] == [
            qos
        ]
    for (tp, _ts, data), (_, _, msg) in zip(raw[:50], msgs[:50]):
        assert bytes(TS.serialize_cdr(msg, by_topic[tp].msgtype)) == data

    # metadata.yaml as rosbag2 (Jazzy) writes it
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert (
        meta["version"] == 9
        and meta["storage_identifier"] == "mcap"
        and meta["ros_distro"] == "jazzy"
    )
    assert (
        meta["relative_file_paths"] == ["run_0.mcap"] and meta["files"][0]["path"] == "run_0.mcap"
    )
    assert meta["message_count"] == len(msgs) and meta["files"][0]["message_count"] == len(msgs)
    assert meta["starting_time"]["nanoseconds_since_epoch"] == msgs[0][1]
    assert meta["duration"]["nanoseconds"] == msgs[-1][1] - msgs[0][1]
    assert meta["custom_data"] == {"run": "unit", "model": "sport"}
    assert meta["compression_format"] == "" and meta["compression_mode"] == ""
    assert sorted(os.listdir(bag)) == ["metadata.yaml", "run_0.mcap"]
    check_summary_crc(mcap_file(bag).read_bytes())

    # our own reader
    assert topic_counts(bag) == {k: len(v) for k, v in expected.items()}
    ours = list(read_messages(bag, topics=["/damper/force"]))
    assert [ts for _, ts, _ in ours] == [ts for ts, _ in expected["/damper/force"]]
    with open_bag(bag) as b:
        assert b.topics["/damper/force"].qos == (qos_f,)
        assert b.start_ns == msgs[0][1] and b.end_ns == msgs[-1][1]


def test_out_of_order_timestamps(tmp_path):
    """Sorted within a flush; any order across flushes once the bag is closed (chunk indexes)."""
    bag = tmp_path / "ooo"
    with BagWriter(bag, flush_period_s=3600, fsync=False) as w:
        c = w.add_topic("/x", F64)
        for t in (50, 10, 30):
            w.write(c, T0 + t, messages.float64(t))
        w.flush()
        msgs, _ = read_rosbags(bag)
        assert [ts - T0 for _, ts, _ in msgs] == [10, 30, 50]
        for t in (20, 5):
            w.write(c, T0 + t, messages.float64(t))
    msgs, _ = read_rosbags(bag)
    assert [ts - T0 for _, ts, _ in msgs] == [5, 10, 20, 30, 50]
    assert [m.data for _, _, m in msgs] == [5, 10, 20, 30, 50]


def test_background_flush_holds_back_the_newest_50_ms(tmp_path, caplog):
    bag = tmp_path / "hold"
    ms = 1_000_000
    w = BagWriter(bag, flush_period_s=3600, fsync=False)

    def background_flush():
        with w._io_lock:
            w._flush_locked(hold_back=True)

    def on_disk():
        with Reader(bag) as reader:
            return [(ts - T0) / ms for _, ts, _ in reader.messages()]

    c = w.add_topic("/x", F64)
    for t in range(100):
        w.write(c, T0 + t * ms, messages.float64(t))
    background_flush()
    assert on_disk() == list(range(50))  # stamped within 50 ms of the newest: held back
    w.write(c, T0 + 60 * ms + 500, messages.float64(-1))  # handed over late, still in order
    background_flush()  # what was held is always written by the next round
    assert on_disk() == sorted([*range(100), 60.0005])
    w.write(c, T0 + 10 * ms, messages.float64(-2))  # far too late for the hold-back
    with caplog.at_level("WARNING"):
        background_flush()  # held back (newest of its round) ...
        background_flush()  # ... and written
    assert "cannot read this bag" in caplog.text
    with pytest.raises(BagError, match="timestamp order"):
        list(read_messages(bag))  # the unclosed file's linear scan refuses it...
    w.close()
    assert on_disk() == sorted([*range(100), 60.0005, 10])  # ...the closed bag is indexed


# ---------------------------------------------------------- live (unclosed) file


def test_valid_after_every_flush_while_open(tmp_path):
    bag = tmp_path / "live"
    w = BagWriter(bag, flush_period_s=3600, fsync=False)
    try:
        assert read_rosbags(bag)[0] == [] and read_mcap(bag)[0] == []
        c = w.add_topic("/damper/state", JS)
        written = []
        for k in range(6):
            if k == 3:  # a topic added after messages were written
                c2 = w.add_topic("/damper/force", F64, qos=Qos(reliability="best_effort", depth=5))
            for i in range(400):
                t = T0 + (k * 400 + i) * 500_000
                w.write(c, t, messages.joint_state(t, ["d"], [i], [0.0], [0.0]))
                written.append(("/damper/state", t))
                if k >= 3:
                    w.write(c2, t + 1, messages.float64(i))
                    written.append(("/damper/force", t + 1))
            w.flush()
            msgs, conns = read_rosbags(bag)
            assert [(tp, ts) for tp, ts, _ in msgs] == written
            raw, _, _, summary = read_mcap(bag)
            assert summary is None
            assert [(tp, ts) for tp, ts, _ in raw] == written
            counts = topic_counts(bag)
            assert sum(counts.values()) == len(written)
            meta = yaml.safe_load((bag / "metadata.yaml").read_text())[
                "rosbag2_bagfile_information"
            ]
            assert meta["message_count"] == len(written)
        assert {c.topic: c.msgcount for c in conns}["/damper/force"] == 3 * 400
    finally:
        w.close()
    msgs, _ = read_rosbags(bag)
    assert [(tp, ts) for tp, ts, _ in msgs] == written


def test_background_flush_writes_without_explicit_flush(tmp_path):
    bag = tmp_path / "bg"
    w = BagWriter(bag, flush_period_s=0.05, fsync=False)
    c = w.add_topic("/x", F64)
    for i in range(100):
        w.write(c, T0 + i, messages.float64(i))
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and topic_counts(bag).get("/x", 0) < 100:
        time.sleep(0.02)
    assert topic_counts(bag) == {"/x": 100}
    w.close()
    w.close()  # no-op


def test_a_disk_slow_to_sync_holds_back_no_write(tmp_path, monkeypatch):
    """Each ``fdatasync`` takes 1 s (a busy machine's disk): the background flushes still
    put every message into the file within a period or two (what a SIGKILL would keep);
    only the syncs fall behind, and :meth:`close` syncs what they had not reached."""
    synced = []
    real_sync = os.fdatasync

    def slow_sync(fd: int) -> None:
        time.sleep(1.0)
        real_sync(fd)
        synced.append(time.monotonic())

    monkeypatch.setattr(os, "fdatasync", slow_sync)
    bag = tmp_path / "slow"
    start = time.monotonic()
    w = BagWriter(bag, flush_period_s=0.05, fsync=True)
    c = w.add_topic("/x", F64)
    behind = []
    for i in range(150):                   # 1.5 s of messages at 100 Hz
        w.write(c, T0 + i, messages.float64(i))
        time.sleep(0.01)
        if i % 25 == 24:                   # what the file holds, read as it is
            behind.append((i + 1) - len(read_mcap(bag)[0]))
    assert synced and synced[0] - start >= 1.0   # the syncs were slow indeed
    # at most 0.05 s hold-back + 0.05 s period + the read: about 10-20 messages behind
    assert max(behind) <= 30, behind
    w.close()
    assert len(read_mcap(bag)[0]) == 150
    assert synced[-1] >= time.monotonic() - 1.0   # close synced before it returned


# ---------------------------------------------------------------- growth


def test_growth_keeps_the_file_readable(tmp_path, monkeypatch):
    monkeypatch.setattr(writer_mod, "_INITIAL_RESERVE", 16 * 1024)
    monkeypatch.setattr(writer_mod, "_MAX_RESERVE", 64 * 1024)
    bag = tmp_path / "grow"
    w = BagWriter(bag, flush_period_s=3600, fsync=False)
    grows = []
    real_grow = w._grow
    w._grow = lambda needed: (grows.append(needed), real_grow(needed))[1]
    c = w.add_topic("/damper/state", JS)
    payload = messages.joint_state(
        T0, ["d"] * 20, np.arange(20.0), np.arange(20.0), np.arange(20.0)
    )
    n = 0
    for k in range(40):
        for _ in range(25):  # ~12 kB per flush
            w.write(c, T0 + n, payload)
            n += 1
        if k == 7:  # one block larger than twice the reserve
            for _ in range(400):
                w.write(c, T0 + n, payload)
                n += 1
        w.flush()
        with Reader(bag) as reader:  # live file, rosbags' scan path
            stamps = [ts for _, ts, _ in reader.messages()]
        assert len(stamps) == n and stamps[-1] == T0 + n - 1
        if k % 5 == 0:
            assert len(read_mcap(bag)[0]) == n
    assert len(grows) >= 5
    assert max(grows) > 2 * 64 * 1024
    w.close()

    data = mcap_file(bag).read_bytes()
    ops = walk_records(data)  # the file ends right after footer + magic: no trailing reserve
    check_summary_crc(data)
    assert all(length == 0 for op, length in ops if op >= 0x80)  # only empty page fillers remain
    assert [op for op, _ in ops if op not in (0x80,)][-3:] == [0x0E, 0x0E, 0x02]
    storage = McapReader(mcap_file(bag))
    storage.open()
    try:
        assert (
            storage.chunks and storage.metadata.message_count == n
        )  # read via the summary's index
    finally:
        storage.close()
    msgs, _ = read_rosbags(bag)
    assert len(msgs) == n
    raw, _, _, summary = read_mcap(bag)
    assert summary is not None and len(raw) == n


def test_growth_window_state_is_still_readable_by_rosbags(tmp_path):
    """Killed between the two writes of a growth: the PAD runs past the end of the file."""
    bag = tmp_path / "window"
    w = BagWriter(bag, flush_period_s=3600, fsync=False)
    try:
        c = w.add_topic("/x", F64)
        for i in range(500):
            w.write(c, T0 + i, messages.float64(i))
        w.flush()
        size = mcap_file(bag).stat().st_size
        new_end = w._reserve_end + 1_000_000
        w._grow_pad(new_end)
        assert mcap_file(bag).stat().st_size == size
        msgs, _ = read_rosbags(bag)
        assert [m.data for _, _, m in msgs] == list(range(500))
        assert [m.data for _, _, m in read_messages(bag)] == list(range(500))
        w._grow_tail(new_end)
        assert mcap_file(bag).stat().st_size == new_end + 50
        assert len(read_mcap(bag)[0]) == 500
        for i in range(500, 600):
            w.write(c, T0 + i, messages.float64(i))
        w.flush()
        assert len(read_rosbags(bag)[0]) == 600
    finally:
        w.close()
    assert len(read_rosbags(bag)[0]) == 600


# ------------------------------------------------------------------- SIGKILL


def _drain(stream, lines):
    for line in stream:
        lines.append(line)


@pytest.mark.slow
@pytest.mark.timing
def test_sigkill_loses_at_most_half_a_second(tmp_path):
    delays = (0.7, 1.1, 1.5)  # s after the first message
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    children = []
    for k in range(len(delays)):
        bag = tmp_path / f"kill{k}"
        proc = subprocess.Popen(
            [sys.executable, str(CHILD), str(bag), "2000"],
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        children.append((bag, proc))
    try:
        outputs = []
        for _, proc in children:
            assert proc.stdout.readline().strip() == "ready"
            lines = []
            threading.Thread(target=_drain, args=(proc.stdout, lines), daemon=True).start()
            outputs.append(lines)
        start = time.monotonic()
        for (_, proc), delay in zip(children, delays):
            time.sleep(max(0.0, start + delay - time.monotonic()))
            proc.send_signal(signal.SIGKILL)
        for _, proc in children:
            proc.wait(timeout=10)
            assert proc.returncode == -signal.SIGKILL
    finally:
        for _, proc in children:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    time.sleep(0.05)

    for (bag, proc), lines, delay in zip(children, outputs, delays):
        proc.stdout.close()
        reported = [tuple(map(int, line.split())) for line in lines if line.endswith("\n")]
        assert len(reported) > 1000 * delay, "child did not run at ~2 kHz"
        msgs, _ = read_rosbags(bag)  # opens, every message decodes
        got = [(ts, round(m.position[0] * 1000)) for _, ts, m in msgs]
        assert got, "nothing recorded"
        assert all(a[0] < b[0] for a, b in itertools.pairwise(got))
        for (ts, i), (_, _, m) in zip(got, msgs):
            assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == ts and m.velocity[0] == i
        # exactly what the child wrote, in order (one written but not yet printed may be extra)
        assert got[: len(reported)] == reported[: len(got)]
        assert len(got) <= len(reported) + 1
        lost_s = (reported[-1][0] - got[-1][0]) / 1e9
        assert lost_s <= 0.5, f"lost {lost_s:.3f} s"
        assert len(read_mcap(bag)[0]) == len(got)
        assert topic_counts(bag) == {"/damper/state": len(got)}


# ---------------------------------------------------------------- bad input


def test_bad_input(tmp_path):
    def one_line(exc_info):
        text = str(exc_info.value)
        assert "\n" not in text and text
        return text

    w = BagWriter(tmp_path / "b", flush_period_s=3600, fsync=False)
    c = w.add_topic("/x", F64)
    other = BagWriter(tmp_path / "o", fsync=False)
    c_other = other.add_topic("/x", F64)
    other.close()
    with pytest.raises(BagError, match="unknown topic") as e:
        w.write(c_other, T0, b"\x00\x01\x00\x00")
    assert str(tmp_path / "b") in one_line(e)
    with pytest.raises(BagError, match="unknown topic"):
        w.write("/x", T0, b"\x00\x01\x00\x00")
    with pytest.raises(BagError, match="unknown topic"):
        w.write([1], T0, b"\x00\x01\x00\x00")
    for bad in ("text", [1, 2], None, 3):
        with pytest.raises(BagError, match="must be bytes") as e:
            w.write(c, T0, bad)
        one_line(e)
    for bad in (-1, 2**64, 1.5, True, "1"):
        with pytest.raises(BagError, match="timestamp_ns"):
            w.write(c, bad, b"\x00\x01\x00\x00")
    w.write(c, np.int64(T0), bytearray(messages.float64(1.0)))  # numpy ints and bytearray are fine
    with pytest.raises(BagError, match="already added"):
        w.add_topic("/x", F64)
    with pytest.raises(BagError, match="unknown message type"):
        w.add_topic("/y", "nope_msgs/msg/Nope")
    with pytest.raises(BagError, match="starting with '/'"):
        w.add_topic("y", F64)
    with pytest.raises(BagError, match="must be one of"):
        Qos(reliability="sometimes")
    w.close()
    with pytest.raises(BagError, match="closed") as e:
        w.write(c, T0, b"\x00\x01\x00\x00")
    one_line(e)
    with pytest.raises(BagError, match="closed"):
        w.add_topic("/z", F64)
    with pytest.raises(BagError, match="closed"):
        w.flush()
    w.close()
    assert topic_counts(tmp_path / "b") == {"/x": 1}

    with pytest.raises(BagError, match="not empty") as e:
        BagWriter(tmp_path / "b")
    one_line(e)
    (tmp_path / "file").write_text("x")
    with pytest.raises(BagError, match="not a directory"):
        BagWriter(tmp_path / "file")
    (tmp_path / "empty").mkdir()
    BagWriter(tmp_path / "empty", fsync=False).close()  # an empty directory is fine
    with pytest.raises(BagError, match="flush_period_s"):
        BagWriter(tmp_path / "p", flush_period_s=0)


def test_open_bag_errors(tmp_path):
    def fails(path, match):
        with pytest.raises(BagError, match=match) as e:
            list(read_messages(path))
        assert "\n" not in str(e.value) and str(path) in str(e.value)

    fails(tmp_path / "missing", "does not exist")
    (tmp_path / "nometa").mkdir()
    fails(tmp_path / "nometa", "no metadata.yaml")
    (tmp_path / "garbage").mkdir()
    (tmp_path / "garbage" / "metadata.yaml").write_text(": : [\n")
    fails(tmp_path / "garbage", "cannot open")

    bag = tmp_path / "good"
    with BagWriter(bag, fsync=False) as w:
        c = w.add_topic("/x", F64)
        w.write(c, T0, messages.float64(1.0))
    mcap = mcap_file(bag)
    good = mcap.read_bytes()
    mcap.write_bytes(os.urandom(len(good)))
    fails(bag, "cannot open")
    mcap.write_bytes(good[: len(good) // 2])
    fails(bag, "cannot open")
    mcap.write_bytes(good)
    assert [m.data for _, _, m in read_messages(bag)] == [1.0]
    with pytest.raises(BagError, match="no topic /nope"):
        list(read_messages(bag, topics=["/nope"]))
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("std_msgs/msg/Float64", "nope_msgs/msg/Nope"))
    fails(bag, "unknown message type")
