"""The reference skyhook controller as its own process on the CAN bus
(``damper-hil skyhook``): ``VEHICLE_MOTION`` frames in, ``VALVE_COMMAND`` frames out.

It stands where an adaptive-damper ECU would: no ROS, only the bus.  Every frame is checked
(length, CRC, alive counter) by the :class:`~can_bridge.codec.Receiver`; the command of the
continuous skyhook law (:func:`ride_sim.skyhook.skyhook_command`) is recomputed at
``skyhook.rate_hz`` from the latest motion and sent.  While no ``VEHICLE_MOTION`` arrives for
``motion_timeout_s`` it sends nothing, so that the bridge falls back to its fail-safe command.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import can

from can_bridge.bus import BusConfig, ResilientBus
from can_bridge.codec import Encoder, Receiver
from can_bridge.core import COMMAND, MOTION
from ride_sim.skyhook import SkyhookParams, SkyhookRates, skyhook_command

#: Silence on VEHICLE_MOTION after which the controller stops commanding [s].
MOTION_TIMEOUT_S = 0.1


@dataclass
class SkyhookStats:
    """What the controller did."""

    motion_frames: int = 0
    commands_sent: int = 0
    commands_failed: int = 0
    silent_periods: int = 0          # times VEHICLE_MOTION went silent
    command_sum: float = 0.0
    command_min: float = 1.0
    command_max: float = 0.0
    dropped: int = 0                 # frames dropped by the receiver (length, CRC, counter)
    lost: int = 0                    # VEHICLE_MOTION frames missing (counter jumps)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["command_mean"] = self.command_sum / self.commands_sent if self.commands_sent else None
        del d["command_sum"]
        return d


def run_skyhook(bus_cfg: BusConfig, db, params: SkyhookParams, rates: SkyhookRates,
                stop: threading.Event, *, motion_timeout_s: float = MOTION_TIMEOUT_S,
                log: Callable[[str], None] | None = None) -> SkyhookStats:
    """Run the controller until ``stop`` is set; returns its statistics."""
    receiver = Receiver(db, [MOTION])
    encoder = Encoder(db, COMMAND)
    stats = SkyhookStats()
    period = 1.0 / params.rate_hz
    latest = None            # (body velocity, damper velocity, arrival)
    silent = True
    next_update = time.monotonic()
    bus_cfg = dataclasses.replace(bus_cfg, receive_ids=receiver.frame_ids)
    with ResilientBus(bus_cfg) as bus:
        while not stop.is_set():
            msg = bus.recv(max(0.0, min(period, next_update - time.monotonic())))
            now = time.monotonic()
            if msg is not None and not msg.is_error_frame:
                got = receiver.accept(msg.arbitration_id, bytes(msg.data))
                if got is not None:
                    stats.motion_frames += 1
                    latest = (float(got.values["BodyVelocity"]),
                              float(got.values["DamperVelocity"]), now)
            if now < next_update:
                continue
            next_update += period
            if now - next_update > period:          # fell behind: no burst of updates
                next_update = now + period
            if latest is None or now - latest[2] > motion_timeout_s:
                if not silent:
                    stats.silent_periods += 1
                    if log:
                        log(f"no VEHICLE_MOTION for {motion_timeout_s:g} s: not commanding")
                silent = True
                continue
            if silent and log:
                log("VEHICLE_MOTION received: commanding")
            silent = False
            command = skyhook_command(latest[0], latest[1], params.c_sky_ns_m, rates,
                                      params.deadband_m_s)
            data, _ = encoder.encode(Command=command)
            if bus.send(can.Message(arbitration_id=encoder.frame_id, data=data,
                                    is_extended_id=False)):
                stats.commands_sent += 1
                stats.command_sum += command
                stats.command_min = min(stats.command_min, command)
                stats.command_max = max(stats.command_max, command)
            else:
                stats.commands_failed += 1
    d = receiver.drops
    stats.dropped, stats.lost = d.dropped, d.lost
    return stats
