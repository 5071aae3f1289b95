"""The live view.  The emulator serves its own view; the layout file's panels name only
channels and fields the view serves.  (``damper-hil demo --live PORT``, the closed loop
with the ``live_view`` node, checked by a WebSocket client against the demo's own bag:
tests/test_demo_run.py.)"""

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
