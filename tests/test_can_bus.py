"""CAN buses through python-can: virtual, udp_multicast between processes, socketcan."""

import multiprocessing
import os
import threading
import time

import can
import pytest

from can_bridge import (
    BusConfig,
    CanBusError,
    Encoder,
    Receiver,
    ResilientBus,
    load_database,
    open_bus,
    socketcan_available,
    socketcan_problem,
)

pytestmark = pytest.mark.can


class FakeClock:
    """A settable monotonic clock for the backoff schedule."""

    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


@pytest.fixture(scope="module")
def db():
    return load_database()


def _channel(tag):
    return f"damper-hil-{tag}-{os.getpid()}-{time.monotonic_ns()}"


def _udp_channel():
    """An interface-local group and a port of this process: no clash with concurrent runs."""
    pid = os.getpid()
    return f"[ff11::dae:{pid >> 16:x}:{pid & 0xFFFF:x}]:{20000 + pid % 30000}"


def _frame(enc, **values):
    data, _ = enc.encode(**values)
    return can.Message(arbitration_id=enc.frame_id, data=data, is_extended_id=False)


# -- configuration and open_bus ---------------------------------------------------------
def test_bus_config_validation():
    cfg = BusConfig()
    assert (cfg.interface, cfg.channel, cfg.bitrate, cfg.receive_own_messages) == (
        "socketcan", "vcan0", 500_000, False)
    for kwargs, match in [
            (dict(interface="socketcann"), "not a python-can interface"),
            (dict(channel=""), "channel"),
            (dict(bitrate=2_000_000), "bitrate"),
            (dict(bitrate=500_000.0), "bitrate"),
            (dict(interface="udp_multicast", channel="10.0.0.1"), "multicast group"),
            (dict(interface="udp_multicast", channel="[ff11::1]:99999"), "port"),
            (dict(interface="udp_multicast", channel="ff11::1", receive_own_messages=True),
             "receive_own_messages")]:
        with pytest.raises(ValueError, match=match) as err:
            BusConfig(**kwargs)
        assert "\n" not in str(err.value)
    udp = BusConfig(interface="udp_multicast", channel="[ff11::1]:43200")
    assert udp.bus_kwargs()["channel"] == "ff11::1" and udp.bus_kwargs()["port"] == 43200
    assert "port" not in BusConfig(interface="udp_multicast", channel="ff11::1").bus_kwargs()
    assert BusConfig(interface="udp_multicast", channel="239.1.2.3:5000").bus_kwargs()[
        "port"] == 5000


def test_open_bus_socketcan_error_is_one_line():
    problem = socketcan_problem("vcan0")
    if problem is None:
        pytest.skip("SocketCAN and vcan0 work here")
    with pytest.raises(CanBusError) as err:
        open_bus(BusConfig(interface="socketcan", channel="vcan0"))
    text = str(err.value)
    assert "\n" not in text and "socketcan:vcan0" in text
    if "kernel has no SocketCAN" in problem:
        assert "udp_multicast" in text and "ff11::" in text and "virtual" in text


def test_socketcan_vcan0_round_trip(db):
    if not socketcan_available("vcan0"):
        pytest.skip(f"socketcan: {socketcan_problem('vcan0')}")
    cfg = BusConfig(interface="socketcan", channel="vcan0")
    with ResilientBus(cfg) as tx, ResilientBus(cfg) as rx:
        assert rx.ensure_open()
        assert tx.send(_frame(Encoder(db, "DAMPER_STATE"), Stroke=0.02, Velocity=0.3))
        receiver = Receiver(db, ["DAMPER_STATE"])
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            msg = rx.recv(0.5)
            if msg is not None and receiver.accept(msg.arbitration_id, msg.data):
                break
        assert receiver.total.accepted == 1


# -- ResilientBus on the virtual interface -----------------------------------------------
def test_virtual_round_trip(db):
    cfg = BusConfig(interface="virtual", channel=_channel("rt"))
    enc = Encoder(db, "DAMPER_FORCE")
    receiver = Receiver(db, ["DAMPER_FORCE"])
    with ResilientBus(cfg) as a, ResilientBus(cfg) as b:
        assert a.state == "idle" and not a.is_up
        assert b.recv(0.0) is None and b.is_up          # lazily opened
        for i in range(20):
            assert a.send(_frame(enc, Force=100.0 * i, Status=0, InputAge=1e-3,
                                 StrokeUsed=1e-3 * i))
        got = []
        while (msg := b.recv(0.2)) is not None:
            got.append(receiver.accept(msg.arbitration_id, msg.data, msg.is_extended_id))
        assert [g.values["Force"] for g in got] == [100.0 * i for i in range(20)]
        assert a.tx_frames == 20 and b.rx_frames == 20 and a.tx_dropped == 0
        assert receiver.total.accepted == 20 and receiver.total.lost == 0
        # error frames are counted, not returned
        peer = can.Bus(interface="virtual", channel=cfg.channel)
        try:
            peer.send(can.Message(is_error_frame=True, arbitration_id=0x20000004, dlc=8,
                                  data=bytes(8)))
            peer.send(_frame(enc, Force=1.0, Status=0, InputAge=0.0, StrokeUsed=0.0))
            msg = b.recv(0.5)
        finally:
            peer.shutdown()
        assert msg is not None and not msg.is_error_frame and b.rx_error_frames == 1
    assert a.state == "closed" and not a.send(_frame(enc, Force=0.0, Status=0, InputAge=0.0,
                                                     StrokeUsed=0.0))
    assert a.recv(1.0) is None


def test_recovery_after_the_bus_breaks(db):
    clock = FakeClock()
    cfg = BusConfig(interface="virtual", channel=_channel("recover"))
    enc = Encoder(db, "VALVE_COMMAND")
    peer = can.Bus(interface="virtual", channel=cfg.channel)
    rb = ResilientBus(cfg, backoff_initial_s=0.05, backoff_max_s=0.2, clock=clock)
    try:
        assert rb.send(_frame(enc, Command=0.1)) and peer.recv(0.5) is not None
        rb._bus.shutdown()                               # broken from outside
        assert not rb.send(_frame(enc, Command=0.2))
        assert rb.state == "down" and not rb.is_up and rb.error_count == 1
        assert "send failed" in rb.last_error and "\n" not in rb.last_error
        assert rb.retry_in_s == pytest.approx(0.05) and rb.backoff_s == pytest.approx(0.1)
        clock.t += 0.04                                  # still backing off: dropped
        assert not rb.send(_frame(enc, Command=0.3))
        assert rb.tx_dropped == 2 and rb.reopen_count == 0
        clock.t += 0.011                                 # backoff over: reopens
        assert rb.send(_frame(enc, Command=0.4))
        assert rb.is_up and rb.reopen_count == 1 and rb.backoff_s == pytest.approx(0.05)
        msg = peer.recv(0.5)
        assert Receiver(db).decode_values(msg.arbitration_id, msg.data)["Command"] == \
            pytest.approx(0.4)
        assert peer.recv(0.0) is None                    # nothing was queued while down

        # receive side, real time: the failure is reported, the bus reopens after the
        # backoff and frames flow again
        rt = ResilientBus(cfg, backoff_initial_s=0.05)
        assert rt.ensure_open()
        rt._bus.shutdown()
        stop = threading.Event()

        def keep_sending():
            while not stop.is_set():
                peer.send(_frame(enc, Command=0.5))
                time.sleep(0.005)

        sender = threading.Thread(target=keep_sending)
        sender.start()
        try:
            t0 = time.monotonic()
            msg = rt.recv(2.0)
            elapsed = time.monotonic() - t0
        finally:
            stop.set()
            sender.join()
            rt.close()
        assert msg is not None and msg.arbitration_id == 0x110
        assert "receive failed" in rt.last_error and rt.reopen_count == 1
        assert elapsed >= 0.05
    finally:
        rb.close()
        peer.shutdown()


def test_backoff_doubles_while_open_fails():
    clock = FakeClock()
    cfg = BusConfig(interface="socketcan", channel="nosuchcan0")   # fails to open anywhere
    rb = ResilientBus(cfg, backoff_initial_s=0.1, backoff_max_s=0.35, clock=clock)
    waits = []
    for _ in range(5):
        assert not rb.send(can.Message(arbitration_id=0x110, data=bytes(8)))
        waits.append(round(rb.retry_in_s, 9))
        clock.t += rb.retry_in_s
    assert waits == [0.1, 0.2, 0.35, 0.35, 0.35]
    assert rb.error_count == 5 and rb.tx_dropped == 5 and rb.state == "down"
    assert rb.last_error.startswith("cannot open CAN bus socketcan:nosuchcan0")
    assert "\n" not in rb.last_error

    # close() from another thread ends a waiting recv
    done = threading.Event()

    def wait():
        rb.recv(None)
        done.set()

    t = threading.Thread(target=wait)
    t.start()
    time.sleep(0.05)
    rb.close()
    assert done.wait(2.0)
    t.join()


# -- udp_multicast between two processes -------------------------------------------------
def _udp_dyno(channel, ready, results, n):
    """Child process: a dyno that answers each DAMPER_STATE with a DAMPER_FORCE."""
    from can_bridge import BusConfig, Encoder, Receiver, ResilientBus, load_database

    db = load_database()
    receiver = Receiver(db, ["DAMPER_STATE"])       # its own echoed frames: unknown_id
    enc = Encoder(db, "DAMPER_FORCE")
    strokes = []
    with ResilientBus(BusConfig(interface="udp_multicast", channel=channel)) as bus:
        ok = bus.ensure_open()
        ready.set()
        deadline = time.monotonic() + 10.0
        while ok and len(strokes) < n and time.monotonic() < deadline:
            msg = bus.recv(0.2)
            decoded = msg and receiver.accept(msg.arbitration_id, msg.data)
            if decoded:
                stroke = decoded.values["Stroke"]
                strokes.append(stroke)
                data, _ = enc.encode(Force=1000.0 * stroke / 0.01, Status=0,
                                     InputAge=2e-4, StrokeUsed=stroke)
                bus.send(can.Message(arbitration_id=enc.frame_id, data=data,
                                     is_extended_id=False))
        results.put((strokes, receiver.total.accepted, receiver.total.dropped,
                     bus.last_error))


def test_udp_multicast_between_processes(db):
    channel = _udp_channel()
    ctx = multiprocessing.get_context("spawn")
    ready, results = ctx.Event(), ctx.Queue()
    n = 20
    child = ctx.Process(target=_udp_dyno, args=(channel, ready, results, n), daemon=True)
    child.start()
    try:
        assert ready.wait(15.0), "the child process did not open its bus"
        enc = Encoder(db, "DAMPER_STATE")
        receiver = Receiver(db, ["DAMPER_FORCE"])
        forces = []
        with ResilientBus(BusConfig(interface="udp_multicast", channel=channel)) as bus:
            for i in range(n):
                assert bus.send(_frame(enc, Stroke=0.001 * i, Velocity=0.05))
                deadline = time.monotonic() + 2.0
                while time.monotonic() < deadline:
                    msg = bus.recv(0.1)
                    decoded = msg and receiver.accept(msg.arbitration_id, msg.data)
                    if decoded:
                        forces.append(decoded)
                        break
        strokes, accepted, dropped, error = results.get(timeout=10.0)
        child.join(5.0)
    finally:
        if child.is_alive():
            child.kill()
    assert error is None
    assert strokes == pytest.approx([0.001 * i for i in range(n)], abs=5e-6)
    assert accepted == n and dropped == 0
    assert [f.values["StrokeUsed"] for f in forces] == pytest.approx(strokes, abs=5e-6)
    assert [f.values["Force"] for f in forces] == pytest.approx(
        [100.0 * i for i in range(n)], abs=0.5)
    assert [f.values["Counter"] for f in forces] == [i % 16 for i in range(n)]
    assert receiver.total.accepted == n and receiver.total.dropped == 0
    assert receiver.total.unknown_id >= n                # our own frames, echoed


def test_receive_ids_filter_out_other_frames():
    """A bus given receive_ids takes only those identifiers (python-can filters)."""
    import can

    from can_bridge.bus import BusConfig, open_bus

    channel = f"filter-{os.getpid()}"
    only = open_bus(BusConfig("virtual", channel, receive_ids=(0x120,)))
    sender = open_bus(BusConfig("virtual", channel))
    try:
        for frame_id in (0x101, 0x120, 0x100, 0x120):
            sender.send(can.Message(arbitration_id=frame_id, data=bytes(8),
                                    is_extended_id=False))
        got = []
        while (msg := only.recv(0.1)) is not None:
            got.append(msg.arbitration_id)
        assert got == [0x120, 0x120]
    finally:
        only.shutdown()
        sender.shutdown()
    with pytest.raises(ValueError, match="11-bit"):
        BusConfig("virtual", channel, receive_ids=(0x800,))


def test_a_receiver_behind_its_bus_filter_never_sees_other_identifiers(db):
    """Why the bridge's /diagnostics has no unknown-identifier count: a bus opened as the
    bridge opens its own (receive_ids = the receiver's frame_ids) hands the receiver only
    its messages, so its ``unknown_id`` stays 0 however much other traffic there is; an
    unfiltered bus on the same channel sees (and its receiver counts) every other frame."""
    channel = _channel("unknown")
    filtered_rx, open_rx = Receiver(db, ["DAMPER_STATE"]), Receiver(db, ["DAMPER_STATE"])
    filtered = ResilientBus(BusConfig("virtual", channel,
                                      receive_ids=filtered_rx.frame_ids))
    unfiltered = ResilientBus(BusConfig("virtual", channel))
    sender = open_bus(BusConfig("virtual", channel))
    state, force = Encoder(db, "DAMPER_STATE"), Encoder(db, "DAMPER_FORCE")
    own, other = 5, 7
    try:
        assert filtered.ensure_open() and unfiltered.ensure_open()
        for k in range(max(own, other)):
            if k < own:
                sender.send(_frame(state, Stroke=0.001 * k, Velocity=0.0))
            if k < other:
                sender.send(_frame(force, Force=1.0, Status=0, InputAge=0.0,
                                   StrokeUsed=0.0))
        for bus, rx in ((filtered, filtered_rx), (unfiltered, open_rx)):
            while (msg := bus.recv(0.1)) is not None:
                rx.accept(msg.arbitration_id, msg.data, msg.is_extended_id)
    finally:
        filtered.close()
        unfiltered.close()
        sender.shutdown()
    assert filtered_rx.total.accepted == own and filtered_rx.total.unknown_id == 0
    assert open_rx.total.accepted == own and open_rx.total.unknown_id == other
