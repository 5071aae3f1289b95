"""A virtual damper dyno on the CAN bus (``damper-hil virtual-rig``).

It plays the dyno of a physical damper in the loop: ``DYNO_COMMAND`` frames in,
``DYNO_FEEDBACK`` (every cycle) and ``DYNO_AUX`` (every ``AUX_PERIOD_S``) frames out.
The physics is :class:`~ride_sim.hybrid.rig.VirtualRig` (transport delay, servo, specimen
damper, sensor noise); this module is its shell: a fixed-rate loop on absolute deadlines
(``SCHED_FIFO`` when permitted) that waits for commands between its cycles.  A cycle it
could not run in time (the host machine stalled) is still simulated, its feedback frame
counted by the alive counter but not sent: the counter tells the host how many cycles
passed.  Every frame
is checked (length, CRC, alive counter) by the :class:`~can_bridge.codec.Receiver` and
takes effect from when it arrived (the kernel's receive stamp, :func:`can_bridge.bus.
receive_time`: a stall of this process does not delay the rig's physics); an
invalid command is dropped and counted, and the rig holds once no valid command has come
for ``rig.hold_after_s``.

:class:`RigFaults` injects what a test of the host's safety layer needs: a transport
delay that changes mid-run, corrupted feedback frames, feedback frames a cycle late,
feedback that stops.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can

from can_bridge.bus import BusConfig, ResilientBus, receive_time
from can_bridge.can_log import CanLog
from can_bridge.codec import Encoder, Receiver
from damper_emulator.realtime.rt import (
    GIL_SWITCH_INTERVAL_S,
    RealtimeReport,
    RealtimeRequest,
    apply_realtime,
)
from ride_sim.hybrid.rig import VirtualRig

COMMAND, FEEDBACK, AUX = "DYNO_COMMAND", "DYNO_FEEDBACK", "DYNO_AUX"
#: Period of ``DYNO_AUX`` [s] (the DBC's cycle time).
AUX_PERIOD_S = 0.1


@dataclass(frozen=True)
class RigFaults:
    """Faults the virtual rig injects (times from the first valid DYNO_COMMAND: from when
    a host took the rig) [s]."""

    #: from this time on the transport delay is ``delay_change_to_s``
    delay_change_at_s: float | None = None
    delay_change_to_s: float = 0.0
    #: every n-th DYNO_FEEDBACK goes out with a wrong checksum (0: none)
    corrupt_every: int = 0
    #: every n-th DYNO_FEEDBACK goes out a cycle late, just before the next one (0: none)
    late_every: int = 0
    #: from this time on no DYNO_FEEDBACK goes out (the rig runs on)
    feedback_stop_at_s: float | None = None


#: The rig logs each time it falls this far behind its cycle [ms] (a stall of the machine).
STALL_LOG_MS = 10.0


@dataclass
class RigStats:
    """What the virtual rig did."""

    cycles: int = 0
    skipped: int = 0                # deadlines skipped after falling behind
    longest_stall_ms: float = 0.0   # the longest time the rig fell behind its cycle (a stall)
    #: each stall of STALL_LOG_MS or more: (its start on the monotonic clock [s], length [ms])
    stalls: list[tuple[float, float]] = field(default_factory=list)
    feedback_sent: int = 0
    corrupted: int = 0              # feedback frames sent with a wrong checksum
    frames: int = 0                 # feedback frames due (a frame held back included)
    late: int = 0                   # feedback frames held back a cycle
    aux_sent: int = 0
    send_failures: int = 0
    commands: int = 0               # valid DYNO_COMMAND frames
    dropped: int = 0                # invalid DYNO_COMMAND frames (length, CRC, counter)
    lost: int = 0                   # DYNO_COMMAND frames missing (counter jumps)
    following_cycles: int = 0       # cycles with Status.enabled
    #: when the transport delay changed (``RigFaults.delay_change_at_s``), on the
    #: monotonic clock [ns] (the host's ``t_monotonic_ns``'s, on one machine)
    delay_changed_ns: int | None = None
    #: with ``feedback_stop_at_s``: when the rig sent its last DYNO_FEEDBACK, and when the
    #: first command with Enable clear after it reached the rig (its kernel's receive
    #: stamp), on the monotonic clock [ns]: the host's watchdog as the rig saw it
    last_feedback_ns: int | None = None
    enable_cleared_ns: int | None = None
    realtime: str = ""

    def as_dict(self) -> dict[str, object]:
        return dataclasses.asdict(self)


def run_virtual_rig(bus_cfg: BusConfig, db, rig: VirtualRig, stop: threading.Event, *,
                    faults: RigFaults = RigFaults(),
                    realtime: RealtimeRequest | None = None,
                    log: Callable[[str], None] | None = None,
                    can_log: CanLog | None = None) -> RigStats:
    """Run the rig until ``stop`` is set; returns its statistics.  ``can_log`` gets every
    frame the rig sends and receives (:class:`~can_bridge.can_log.CanLog`)."""
    receiver = Receiver(db, [COMMAND])
    feedback_enc = Encoder(db, FEEDBACK)
    aux_enc = Encoder(db, AUX)
    stats = RigStats()
    report: RealtimeReport | None = apply_realtime(realtime) if realtime is not None \
        else None
    if report is not None:
        stats.realtime = report.summary()
    period = rig.period_s
    aux_every = max(1, round(AUX_PERIOD_S / period))
    bus_cfg = dataclasses.replace(bus_cfg, receive_ids=receiver.frame_ids)
    changed = False
    switch = sys.getswitchinterval()
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    try:
        with ResilientBus(bus_cfg, log=can_log) as bus:
            t0 = time.monotonic()
            deadline = t0
            first_command: float | None = None
            j = 0
            offset = time.time() - time.monotonic()
            held: can.Message | None = None     # a feedback frame sent a cycle late
            stopped = False         # the feedback has stopped (RigFaults.feedback_stop_at_s)
            while not stop.is_set():
                msg = bus.recv(max(0.0, deadline - time.monotonic()))
                while msg is not None:      # every command that has come, at its time
                    got = receiver.accept(msg.arbitration_id, bytes(msg.data),
                                          msg.is_extended_id)
                    if got is not None:
                        stats.commands += 1
                        if first_command is None:
                            first_command = time.monotonic() - t0
                        v = got.values
                        at = receive_time(msg, offset)
                        rig.command(at - t0, float(v["StrokeDemand"]),
                                    bool(v["Enable"]), float(v["VelocityDemand"]))
                        if (stopped and not v["Enable"]
                                and stats.enable_cleared_ns is None):
                            stats.enable_cleared_ns = int(at * 1e9)
                    msg = bus.recv(0.0)
                if time.monotonic() < deadline:
                    continue
                t = deadline - t0
                # the faults' clock starts with the first valid command: before it, none
                # acts (the rig sends its feedback, at its first delay, as a dyno does)
                taken = -math.inf if first_command is None else t - first_command
                if (faults.delay_change_at_s is not None and not changed
                        and taken >= faults.delay_change_at_s):
                    rig.set_delay(faults.delay_change_to_s)
                    changed = True
                    stats.delay_changed_ns = int(deadline * 1e9)
                    if log:
                        log(f"transport delay now {faults.delay_change_to_s * 1e3:g} ms")
                fb = rig.step(t)
                stats.cycles += 1
                if rig.following:
                    stats.following_cycles += 1
                stopped = (faults.feedback_stop_at_s is not None
                           and taken >= faults.feedback_stop_at_s)
                if not stopped:
                    data, _ = feedback_enc.encode(StrokeMeasured=fb.stroke_m,
                                                  Force=fb.force_n, Status=fb.status)
                    if faults.corrupt_every and stats.feedback_sent % faults.corrupt_every \
                            == faults.corrupt_every - 1:
                        data = data[:-1] + bytes([data[-1] ^ 0xFF])
                        stats.corrupted += 1
                    frame = can.Message(arbitration_id=feedback_enc.frame_id, data=data,
                                        is_extended_id=False)
                    due = [frame]
                    if held is not None:
                        due, held = [held, frame], None
                    if faults.late_every and stats.frames % faults.late_every \
                            == faults.late_every - 1:
                        held = due.pop()
                        stats.late += 1
                    stats.frames += 1
                    for m in due:
                        if bus.send(m):
                            stats.feedback_sent += 1
                            if faults.feedback_stop_at_s is not None:
                                stats.last_feedback_ns = time.monotonic_ns()
                        else:
                            stats.send_failures += 1
                if j % aux_every == 0:
                    data, _ = aux_enc.encode(Temperature=fb.temperature_c)
                    if bus.send(can.Message(arbitration_id=aux_enc.frame_id, data=data,
                                            is_extended_id=False)):
                        stats.aux_sent += 1
                j += 1
                deadline += period
                behind = time.monotonic() - deadline
                stats.longest_stall_ms = max(stats.longest_stall_ms, behind * 1e3)
                if behind * 1e3 >= STALL_LOG_MS:
                    stats.stalls.append((deadline, behind * 1e3))
                if behind > period:
                    # fell behind: the physics runs through the missed cycles, without a
                    # burst of frames
                    for _ in range(int(behind / period)):
                        fb = rig.step(deadline - t0)
                        # the cycle's frame is not sent, but counted: the counter tells the
                        # host how many cycles passed
                        feedback_enc.encode(StrokeMeasured=fb.stroke_m, Force=fb.force_n,
                                            Status=fb.status)
                        stats.skipped += 1
                        deadline += period
                        j += 1
    finally:
        sys.setswitchinterval(switch)
        if report is not None:
            report.restore()
    d = receiver.drops
    stats.dropped, stats.lost = d.dropped, d.lost
    return stats
