"""The host of a physical damper on the CAN bus (``damper-hil hybrid``, ``dyno`` on a rig).

:func:`run_hybrid_link` drives a :class:`~ride_sim.hybrid.rig_host.RigHost` (the ride's
:class:`~ride_sim.hybrid.host.HybridHost` or a protocol's
:class:`~ride_sim.hybrid.protocol_host.ProtocolHost`) from a dyno's frames: the host runs
one cycle per valid ``DYNO_FEEDBACK`` as soon as it arrives and sends the ``DYNO_COMMAND``
at once (the dyno's clock paces the loop: the command goes out a computation after the
feedback it used).  With the loop pinned to a CPU (``--cpu``), the host sleeps until
``poll_before_s`` (the run's parameters) before a feedback is due and polls the bus from
then on: the frame is read as it lands, without the scheduler's wake-up (on a virtual
machine, the halted CPU's return too).
The run advances one step per cycle of the rig, counted by the feedback's
alive counter: a cycle whose feedback does not come (lost or invalid) runs
``MISSED_FEEDBACK_PERIODS`` periods after the last one on the last measurement (the watchdog
keeps counting).  A feedback that comes after its cycle ran that way is put in its place
(:meth:`~ride_sim.hybrid.rig_host.RigHost.late`); one whose counter says frames were lost
runs their cycles first, on the last measurement, and then its own.  The run's samples so
stay on the dyno's cycles, and those without their own measurement are marked
(:attr:`~ride_sim.hybrid.rig_host.RigHost.fresh`).
``DYNO_AUX`` updates the oil temperature. Frames with a wrong length, checksum or counter
are dropped and counted by the :class:`~can_bridge.codec.Receiver` and never reach the host:
they are not valid feedback.

When the host has finished, or ``stop`` is set (``stopped`` by the user: the host's safety
layer records the reason), a few commands with ``Enable`` clear go out.
"""

from __future__ import annotations

import dataclasses
import gc
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import numpy as np

from can_bridge.bus import BusConfig, ResilientBus, open_bus, receive_time
from can_bridge.can_log import CanLog
from can_bridge.codec import Encoder, Receiver
from can_bridge.dbc import COUNTER_CYCLES
from damper_emulator.realtime.rt import (
    GIL_SWITCH_INTERVAL_S,
    RealtimeReport,
    RealtimeRequest,
    apply_realtime,
)
from ride_sim.hybrid.rig import Feedback
from ride_sim.hybrid.rig_host import MISSED_FEEDBACK_PERIODS, Command, RigHost

COMMAND, FEEDBACK, AUX = "DYNO_COMMAND", "DYNO_FEEDBACK", "DYNO_AUX"
#: Commands with Enable clear sent at the end.
FINAL_COMMANDS = 5


@dataclass
class LinkStats:
    """What the host's link did."""

    feedback: int = 0                # valid DYNO_FEEDBACK frames
    aux: int = 0                     # valid DYNO_AUX frames
    dropped: int = 0                 # invalid frames (length, checksum, counter)
    dropped_checksum: int = 0
    lost: int = 0                    # frames missing (counter jumps)
    cycles_without_feedback: int = 0
    #: feedback frames that came after their cycle had run on a timeout: put in its place
    late_feedback: int = 0
    commands_sent: int = 0
    send_failures: int = 0
    saturated_commands: int = 0      # a value outside its DBC range, sent saturated
    temperature_c: float = math.nan  # the latest DYNO_AUX
    dyno_status_bits: int = 0        # OR of every DYNO_FEEDBACK Status
    realtime: str = ""
    poll_before_s: float = 0.0       # the polling the loop used (0 unless pinned to a CPU)
    #: feedback arrival → its command sent [µs], one per cycle run on a feedback
    response_us: list[float] = field(default_factory=list, repr=False)
    #: when each of those feedback frames arrived [ns, monotonic]
    response_at_ns: list[int] = field(default_factory=list, repr=False)
    #: of each response, the part before the host read the frame (the wake-up, the
    #: interface's receive) [µs]
    read_us: list[float] = field(default_factory=list, repr=False)

    def summary(self) -> dict[str, object]:
        d = {k: v for k, v in dataclasses.asdict(self).items()
             if k not in ("response_us", "response_at_ns", "read_us")}
        for name, values in (("response", self.response_us), ("read", self.read_us)):
            r = np.asarray(values)
            d[f"{name}_p50_us"] = float(np.percentile(r, 50)) if r.size else math.nan
            d[f"{name}_p99_us"] = float(np.percentile(r, 99)) if r.size else math.nan
            d[f"{name}_max_us"] = float(r.max()) if r.size else math.nan
        return d


def _receive(bus: ResilientBus, poll_from: float, deadline: float) -> can.Message | None:
    """The next frame by ``deadline`` [s, monotonic]: asleep until ``poll_from``, then
    polling (a frame due soon is read as it lands, not a wake-up later)."""
    wake = min(poll_from, deadline)
    now = time.monotonic()
    if now < wake:
        msg = bus.recv(wake - now)
        if msg is not None:
            return msg
    while time.monotonic() < deadline:
        msg = bus.recv(0.0)
        if msg is not None:
            return msg
    # past the deadline, a frame that came while this process was held up is still read:
    # without it, a stall of the host would run a cycle without the feedback that waited
    return bus.recv(0.0)


def dyno_answers(bus_cfg: BusConfig, db, timeout_s: float) -> bool:
    """Whether a ``DYNO_FEEDBACK`` comes on ``bus_cfg`` within ``timeout_s``: the check a
    run makes before it builds anything (its host, a characterisation), so that a user
    with no dyno on the bus hears so at once."""
    frame_id = db.get_message_by_name(FEEDBACK).frame_id
    bus = open_bus(dataclasses.replace(bus_cfg, receive_ids=(frame_id,)))
    try:
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0.0:
            msg = bus.recv(left)
            if msg is not None and msg.arbitration_id == frame_id:
                return True
        return False
    finally:
        bus.shutdown()


def run_hybrid_link(bus_cfg: BusConfig, db, host: RigHost, stop: threading.Event, *,
                    realtime: RealtimeRequest | None = None,
                    progress: Callable[[str], None] | None = None,
                    can_log: CanLog | None = None) -> LinkStats:
    """Run ``host`` against the dyno on ``bus_cfg`` until it has finished or ``stop`` is
    set; returns the link's statistics.  ``can_log`` gets every frame the link sends and
    receives (:class:`~can_bridge.can_log.CanLog`)."""
    receiver = Receiver(db, [FEEDBACK, AUX])
    encoder = Encoder(db, COMMAND)
    stats = LinkStats()
    report: RealtimeReport | None = apply_realtime(realtime) if realtime is not None \
        else None
    if report is not None:
        stats.realtime = report.summary()
    period = host.dt_s
    # polling pays only on a CPU of the loop's own: unpinned, it takes the CPU the other
    # processes of the run (the writer, on a small machine the dyno's) need
    poll = host.run.poll_before_s if report is not None and report.pinned else 0.0
    stats.poll_before_s = poll
    bus_cfg = dataclasses.replace(bus_cfg, receive_ids=receiver.frame_ids)
    phase = host.phase

    def send(command_stroke: float, velocity: float, enable: bool) -> None:
        data, saturated = encoder.encode(StrokeDemand=command_stroke,
                                         VelocityDemand=velocity, Enable=int(enable))
        if saturated:
            stats.saturated_commands += 1
        if bus.send(can.Message(arbitration_id=encoder.frame_id, data=data,
                                is_extended_id=False)):
            stats.commands_sent += 1
        else:
            stats.send_failures += 1

    switch = sys.getswitchinterval()
    # a loop waiting for the GIL waits at most this long for a Python thread that holds it
    # (the recorder; the default 5 ms is five cycles)
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    gc.collect()
    gc.freeze()          # the start-up's objects: out of the collector's way
    def cycle(now: float, feedback: Feedback | None, arrival_ns: int | None) -> None:
        nonlocal phase
        command = host.cycle(now, feedback, now_s=time.monotonic())
        # a stall of the host while it ran the cycle (SIGSTOP, the VM halting it): the
        # command is stale, and the safety layer's stop goes out in its place
        host.safety.host_wakes(time.monotonic())
        if command.enable and not host.safety.enable:
            command = Command(host.demand_m, 0.0, False)
        send(*command)
        sent_ns = time.monotonic_ns()
        host.stamp(sent_ns)
        if arrival_ns is not None:
            stats.response_us.append((sent_ns - arrival_ns) / 1e3)
            stats.response_at_ns.append(arrival_ns)
        host.after_send()
        if progress is not None and host.phase != phase:
            phase = host.phase
            progress(phase)

    try:
        with ResilientBus(bus_cfg, log=can_log) as bus:
            last_cycle = time.monotonic()
            offset = time.time() - time.monotonic()
            last_counter: int | None = None
            ran_without = 0         # cycles run on a timeout since the last feedback
            while not host.finished:
                if stop.is_set():
                    host.safety.stop(time.monotonic(), "stopped by the user")
                    break
                deadline = last_cycle + MISSED_FEEDBACK_PERIODS * period
                msg = _receive(bus, last_cycle + period - poll, deadline)
                read_ns = time.monotonic_ns()
                host.safety.host_wakes(read_ns * 1e-9)
                # when it arrived (the kernel's stamp): the response time counts a stall
                arrival = read_ns * 1e-9 if msg is None else receive_time(msg, offset)
                arrival_ns = int(arrival * 1e9)
                if msg is None:
                    if arrival < deadline:
                        continue
                    # no feedback this cycle: run it on the last measurement (the watchdog
                    # counts on)
                    stats.cycles_without_feedback += 1
                    ran_without += 1
                    cycle(arrival, None, None)
                    last_cycle = arrival - (MISSED_FEEDBACK_PERIODS - 1.0) * period
                    continue
                got = receiver.accept(msg.arbitration_id, bytes(msg.data), msg.is_extended_id)
                if got is None:
                    continue
                if got.name == AUX:
                    stats.aux += 1
                    stats.temperature_c = float(got.values["Temperature"])
                    continue
                v = got.values
                status = int(v["Status"])
                stats.dyno_status_bits |= status
                stats.feedback += 1
                feedback = Feedback(float(v["StrokeMeasured"]), float(v["Force"]), status,
                                    stats.temperature_c)
                counter = int(v["Counter"])
                # the rig's cycles since the last feedback, by its alive counter: the car
                # advances one step per rig cycle whatever the bus lost or delayed
                elapsed = 1 if last_counter is None else (
                    (counter - last_counter) % COUNTER_CYCLES or COUNTER_CYCLES)
                last_counter = counter
                if ran_without >= COUNTER_CYCLES:
                    # more cycles ran without feedback than the counter can tell apart:
                    # the newest measurement, in no sample's place
                    ran_without = 0
                    host.measure(arrival, feedback)
                elif elapsed <= ran_without:    # its cycle already ran on the timeout
                    ran_without -= elapsed
                    stats.late_feedback += 1
                    host.late(arrival, feedback, ran_without)
                else:
                    # lost frames: their cycles first, on the last measurement, then this
                    # one's: each sample of the run is its own cycle's measurement or held
                    for _ in range(elapsed - ran_without - 1):
                        cycle(arrival, None, None)
                    ran_without = 0
                    stats.read_us.append((read_ns - arrival_ns) / 1e3)
                    cycle(arrival, feedback, arrival_ns)
                last_cycle = arrival
            for _ in range(FINAL_COMMANDS):
                send(host.demand_m, 0.0, False)
    finally:
        sys.setswitchinterval(switch)
        gc.unfreeze()
        if report is not None:
            report.restore()
    d = receiver.drops
    stats.dropped, stats.dropped_checksum, stats.lost = d.dropped, d.checksum, d.lost
    return stats
