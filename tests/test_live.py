"""The live view.  ``damper-hil demo --live PORT`` runs the closed loop with the
``live_view`` node; a WebSocket client in the test speaks the Foxglove WebSocket protocol
to it while the demo runs (subscribes to every advertised channel, decodes the binary
message frames and their JSON payloads) and checks what it receives against the demo's own
bag, read back independently: the forces the view sent are forces the emulator published.
The layout file's panels name only channels and fields the view serves."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import pytest
from live_client import connect_when_up

from damper_emulator.ros.live import CHANNELS

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
#: away from the other tests' ROS domains (test_lifecycle.py: 150..152, 154..156)
DOMAIN = 153


def test_the_live_view_serves_the_running_demo(cold_demo_run):
    """The shared cold run of ``damper-hil demo --live`` (conftest.py), with a WebSocket
    client listening from its start to its end."""
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    run = cold_demo_run
    out, channels, got = run.out, run.channels, run.got
    assert run.proc.returncode == 0, run.proc.stderr[-2000:]
    assert not run.client_error, run.client_error
    # every channel advertised with its JSON schema
    advertised = {c["topic"]: c for c in channels}
    assert set(advertised) == set(CHANNELS)
    for topic, c in advertised.items():
        assert c["encoding"] == "json" and c["schemaName"] == CHANNELS[topic][0]
        assert set(json.loads(c["schema"])["properties"]) == set(CHANNELS[topic][1])
    damper, ride, loop = got.get("/live/damper", []), got.get("/live/ride", []), \
        got.get("/live/loop", [])
    assert len(damper) > 200, {k: len(v) for k, v in got.items()}   # 250 Hz for seconds
    assert len(ride) > 20 and loop
    assert all(set(m) == set(CHANNELS["/live/damper"][1]) for m in damper)
    assert all(math.isfinite(m["force_n"]) for m in damper)
    # the ride's r.m.s. values accumulate: finite, and the sample count grows
    counts = [m["samples"] for m in ride]
    assert counts == sorted(counts) and counts[-1] > counts[0]
    assert all(m["accel_w_rms_m_s2"] > 0 and m["dtl_rms_n"] > 0 for m in ride[5:])
    # the emulator loop's figures (their values are the host's: benchmarks measure them)
    assert any(m["achieved_rate_hz"] and m["achieved_rate_hz"] > 0 for m in loop)
    # the forces the view sent are forces the emulator published: in the demo's bag, read
    # back with rosbags (not the project's reader)
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    recorded = set()
    with Reader(out / "bag") as reader:
        conns = [c for c in reader.connections if c.topic == "/damper/force"]
        for conn, _ts, data in reader.messages(connections=conns):
            m = typestore.deserialize_cdr(data, conn.msgtype)
            if len(m.position) and len(m.effort):
                recorded.add((round(float(m.position[0]), 12), round(float(m.effort[0]), 9)))
    live = [(round(m["stroke_m"], 12), round(m["force_n"], 9)) for m in damper
            if m["stroke_m"] is not None]
    found = sum(p in recorded for p in live)
    assert found >= 0.95 * len(live), f"{found} of {len(live)} live samples in the bag"
    summary = json.loads((out / "demo.json").read_text())
    assert summary["live_port"] == run.port


def test_the_layout_shows_what_the_view_serves():
    layout = json.loads((ROOT / "config" / "foxglove_layout.json").read_text())
    fields = {f"{topic}.{name}" for topic, (_, spec) in CHANNELS.items() for name in spec}
    paths = []
    for panel, config in layout["configById"].items():
        for p in config.get("paths", []):
            paths.append(p["value"])
        if "xAxisPath" in config:
            paths.append(config["xAxisPath"]["value"])
        if "topicPath" in config:
            assert config["topicPath"] in CHANNELS, panel
    assert paths and set(paths) <= fields, set(paths) - fields
    # force against velocity and against time, and a status panel, are laid out
    assert {"/live/damper.force_n", "/live/damper.velocity_m_s"} <= set(paths)

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(
            node["second"])
    assert set(leaves(layout["layout"])) == set(layout["configById"])


def test_the_emulator_serves_its_own_live_view(tmp_path):
    """``emulator.live_port``: the emulator alone (a dyno rig without the ride) serves
    ``/live/damper`` and ``/live/loop`` from its executor thread."""
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    import socket
    import threading

    from ros_probe import Probe
    from sensor_msgs.msg import JointState
    from test_bridge import start_node

    from damper_emulator import topics
    from damper_emulator.ros.common import control_qos, set_stamp

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    node = start_node("emulator", "emulate", DOMAIN, tmp_path, {
        "emulator.live_port": port, "emulator.diagnostics_period_s": 0.2})
    probe = Probe(DOMAIN)
    stop = threading.Event()
    try:
        states = probe.node.create_publisher(JointState, topics.STATE, control_qos(10))

        def feed() -> None:
            while not stop.is_set():
                msg = JointState(name=["damper"], position=[0.012], velocity=[0.0])
                set_stamp(msg.header.stamp, time.time_ns())
                states.publish(msg)
                time.sleep(0.002)

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        channels, got = connect_when_up(port, time.monotonic() + 120, seconds=4.0)
    finally:
        stop.set()
        probe.close()
        node.stop()
    assert {c["topic"] for c in channels} == set(CHANNELS)
    damper = [m for m in got.get("/live/damper", []) if m["status"] == 0]
    assert len(damper) > 50, {k: len(v) for k, v in got.items()}     # 50 Hz for seconds
    assert all(m["stroke_m"] == pytest.approx(0.012) and math.isfinite(m["force_n"])
               for m in damper)
    assert got.get("/live/loop") and "/live/ride" not in got          # no ride in this rig
    assert "Traceback" not in node.log_path.read_text()
