"""The one run of ``damper-hil demo --live`` (conftest.py's ``demo_run``: as ``make demo``
runs it for a new user, with a live-view client listening), checked by each of its
readers: the start-up and the loops' compile state, the bag (read back with
rosbags), and the live view.  One module, so that a test runner's worker runs the demo
once for all three (``make test``: ``--dist loadfile``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags_reader import TYPESTORE, read_bag

from damper_emulator import topics
from damper_emulator.ros.live import CHANNELS

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_demo_runs_every_sample_with_nothing_compiled_after_ready(demo):
    """`damper-hil demo` as a new user runs it after ``make``'s install (the ``demo``
    fixture).  It exits 0, the ride runs every sample, the emulator says when it became
    active, and nothing is compiled once it is: the start-up a compile would otherwise
    stall.  Whether the loops then kept pace with the wall clock, and how soon the
    emulator was active, are figures of the host (the report gives them;
    benchmarks/demo_bench.py measures them, cold and warm), not a pass or fail here."""
    proc, out = demo
    figures = ""
    if (out / "demo.json").is_file():
        doc = json.loads((out / "demo.json").read_text())
        loop = doc.get("emulator_loop", {})
        figures = (f"real-time factor {doc['ride'].get('real_time_factor')}, ride loop "
                   f"{json.dumps(doc['ride'].get('loop'))}, emulator {json.dumps(loop)}, "
                   f"fault outputs after the first input "
                   f"{doc.get('fault_outputs_after_first_input')}, emulator active after "
                   f"{doc.get('emulator_active_after_s')} s")
    assert proc.returncode == 0, f"{proc.stderr[-2000:]}\n{figures}"
    doc = json.loads((out / "demo.json").read_text())
    ride = doc["ride"]
    assert ride["samples"] == 6001 and ride["lead_in_samples"] == 1000, ride
    assert doc["emulator_active_after_s"] is not None, doc
    assert doc["kernels_compiled_after_ready"] == 0, figures
    assert doc["emulator_loop"]["compiled_after_ready"] == 0, figures
    assert 0 < ride["real_time_factor"] <= 1.01, figures
    print(figures)


def test_closed_loop_demo_writes_a_bag_rosbags_reads(demo):
    """The demo's closed loop recorded every topic, and rosbags reads the bag."""
    proc, out = demo
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((out / "demo.json").read_text())
    msgs = read_bag(out / "bag")
    for topic in (topics.STATE, topics.FORCE, topics.RIDE_STATE, topics.DIAGNOSTICS):
        assert msgs.get(topic), f"{topic} not recorded"
    n_state = len(msgs[topics.STATE])
    assert n_state == 6001, f"{n_state} /damper/state recorded"  # (5 s + 1 s lead-in) at 1 kHz
    forces = np.array([m.effort[0] for _, m in msgs[topics.FORCE]])
    assert np.isfinite(forces).all() and len(forces) >= 0.95 * n_state, len(forces)
    with Reader(out / "bag") as reader:
        for conn in reader.connections:
            assert conn.ext.offered_qos_profiles, conn.topic
            assert conn.ext.serialization_format == "cdr"
    m = summary["ride"]["metrics"]
    # the loop delay: every sample after the emulator's first force answers an earlier
    # state (causality: at least one sample), and the verdict agrees with the figures
    delay = summary["ride"]["loop_delay"]
    assert delay["samples"] > 0.9 * n_state and delay["p50_ms"] >= 1.0, delay
    assert delay["within_bound"] == (delay["max_ms"] <= delay["bound_ms"]), delay
    # a real-time loop on a busy 2-core machine may see stale-input faults; the physics is
    # checked exactly by the lockstep test.  Here: the closed loop rode the minor road
    # (offline: SWS 32 mm, DTL 1.66 kN r.m.s.) and did not fall apart.
    # (with the skyhook controller commanding the damper over CAN: SWS +11 %, DTL +21 %)
    if not delay["within_bound"]:
        assert "the loop delay exceeded its bound" in proc.stdout + proc.stderr, delay
    if delay["p99_ms"] <= delay["bound_ms"]:
        assert 0.016 < m["sws_rms"] < 0.064 and 800 < m["dtl_rms"] < 4000, m
    # else: a slow host; the run says so (above) and its metrics are not the damper's.
    # The case this guards: on a two-core machine the force the ride applied could answer
    # a state up to 0.75 s old, which pumped the wheel hop, when the ride's DDS threads ran
    # under normal scheduling behind the other nodes' SCHED_FIFO ones (ride.dds_priority)
    assert summary["valve_command"]["count"] > 100, summary["valve_command"]
    assert summary["bridge_diagnostics"], "no /diagnostics from the CAN bridge recorded"
    for f in ("ride.png", "damper.png", "control.png", "loop.png", "report.md", "demo.json"):
        assert (out / f).stat().st_size > 0


def test_the_demos_time_series_as_mdf4_are_the_bags(demo):
    """``--format mf4``: demo.mf4 holds the recorded topics, a channel group each, with
    units and comments; read by asammdf, its forces and ride are the bag's as rosbags
    decodes them, on the bag's stamps."""
    from asammdf import MDF

    proc, out = demo
    assert proc.returncode == 0, proc.stderr[-2000:]
    msgs = read_bag(out / "bag")
    mdf = MDF(out / "demo.mf4")
    try:
        comments = [g.channel_group.comment for g in mdf.groups]
        assert comments[:3] == [topics.STATE, topics.FORCE, topics.RIDE_STATE], comments
        force = mdf.get("force")
        assert force.unit == "N" and "rebound positive" in force.comment
        recorded = msgs[topics.FORCE]
        assert np.array_equal(force.samples, [m.effort[0] for _, m in recorded])
        stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                           for _, m in recorded])
        assert np.allclose(np.diff(force.timestamps), np.diff(stamps) * 1e-9, atol=1e-9)
        assert "NO_INPUT" in mdf.get("status").comment
        assert np.array_equal(mdf.get("stroke").samples,
                              [m.position[0] for _, m in msgs[topics.STATE]])
        assert mdf.get("dtl").unit == "N" and mdf.get("wheel").unit == "m"
        assert mdf.get("valve_command").samples.size > 100
    finally:
        mdf.close()


def test_the_live_view_serves_the_running_demo(demo_run):
    """The shared run of ``damper-hil demo --live`` (conftest.py), with a WebSocket
    client listening from its start to its end."""
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    run = demo_run
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
    recorded = set()
    with Reader(out / "bag") as reader:
        conns = [c for c in reader.connections if c.topic == "/damper/force"]
        for conn, _ts, data in reader.messages(connections=conns):
            m = TYPESTORE.deserialize_cdr(data, conn.msgtype)
            if len(m.position) and len(m.effort):
                recorded.add((round(float(m.position[0]), 12), round(float(m.effort[0]), 9)))
    live = [(round(m["stroke_m"], 12), round(m["force_n"], 9)) for m in damper
            if m["stroke_m"] is not None]
    found = sum(p in recorded for p in live)
    assert found >= 0.95 * len(live), f"{found} of {len(live)} live samples in the bag"
    summary = json.loads((out / "demo.json").read_text())
    assert summary["live_port"] == run.port
