"""A dyno on the CAN bus: run a displacement history against whatever answers
``DAMPER_STATE`` with ``DAMPER_FORCE`` (the bridge in dyno mode in front of the emulator),
the way a CAN dyno does.  No ROS here: python-can and the codec only.

:func:`run_over_can` sends one ``DAMPER_STATE`` frame per sample at the history's own rate
from a fixed-rate loop (absolute deadlines, ``SCHED_FIFO`` when permitted) and collects the
``DAMPER_FORCE`` frames on a receive thread.  The emulator must answer every sample
(``emulator.trigger: input``): the forces are paired with the samples in order, and the pairing
is checked against the ``StrokeUsed`` each force frame carries.

Start-up: the first sample is sent repeatedly until a force computed from it comes back
(the bridge and the emulator are connected), then the dyno waits longer than the model's
``settle_gap_s`` so that the emulator restarts from quasi-steady equilibrium at the first
sample, as the offline model does (:func:`damper_emulator.model.compressible.simulate`).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import numpy as np

from can_bridge.bus import BusConfig, ResilientBus
from can_bridge.codec import Encoder, Receiver
from can_bridge.core import FORCE, STATE
from can_bridge.dbc import ForceStatus
from damper_emulator.errors import DamperHilError
from damper_emulator.realtime.loop import PeriodicLoop
from damper_emulator.realtime.rt import RealtimeRequest


class OverCanError(DamperHilError, RuntimeError):
    """The run over CAN could not be completed (one line: what is missing)."""


@dataclass
class OverCanResult:
    """Forces received for the samples sent (NaN where none came back)."""

    force_n: np.ndarray
    status: np.ndarray            # DAMPER_FORCE Status bits per sample (-1: no force)
    stroke_used_m: np.ndarray
    latency_s: np.ndarray         # send → force arrival (NaN: none)
    sent: int = 0
    received: int = 0
    fault_frames: int = 0         # DAMPER_FORCE frames flagged FORCE_TIMEOUT (not forces)
    stroke_mismatches: int = 0    # forces whose StrokeUsed is not the sample's stroke
    dropped: dict = field(default_factory=dict)
    elapsed_s: float = 0.0
    #: largest deviation of a sample's send interval from the nominal one [s]: the emulator
    #: steps by the frames' times, so a dyno that stalls changes what it simulates
    send_interval_error_max_s: float = 0.0


def run_over_can(t: np.ndarray, x: np.ndarray, v: np.ndarray, bus_cfg: BusConfig, db, *,
                 settle_gap_s: float = 0.1, connect_timeout_s: float = 20.0,
                 drain_timeout_s: float = 1.0,
                 progress: Callable[[str], None] | None = None) -> OverCanResult:
    """Send the history ``(t, x, v)`` (uniform ``t`` [s], stroke [m], velocity [m/s]) as
    ``DAMPER_STATE`` frames at its own rate and collect the forces.

    Raises
    ------
    OverCanError
        No force comes back within ``connect_timeout_s``, or the bus fails.
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    if n < 2:
        raise OverCanError("need at least two samples")
    dt = float(np.median(np.diff(t)))
    state_enc = Encoder(db, STATE)
    receiver = Receiver(db, [FORCE])
    stroke_step = float(db.get_message_by_name(STATE).get_signal_by_name("Stroke").scale)
    bus = ResilientBus(dataclasses.replace(bus_cfg, receive_ids=receiver.frame_ids))
    force = np.full(n, np.nan)
    status = np.full(n, -1, dtype=np.int64)
    stroke_used = np.full(n, np.nan)
    arrival = np.zeros(n, dtype=np.int64)
    sent_ns = np.zeros(n, dtype=np.int64)
    fault_bit = int(ForceStatus.FORCE_TIMEOUT)
    shared = {"next": 0, "recording": False, "primed": False, "faults": 0}
    stop = threading.Event()

    def receive() -> None:
        while not stop.is_set():
            msg = bus.recv(0.05)
            if msg is None or msg.is_error_frame:
                continue
            got = receiver.accept(msg.arbitration_id, bytes(msg.data))
            if got is None:
                continue
            now = time.monotonic_ns()
            values = got[1]
            bits = int(values["Status"])
            if bits & fault_bit:
                shared["faults"] += 1
                continue
            if not shared["recording"]:
                shared["primed"] = True
                continue
            k = shared["next"]
            if k < n:
                force[k] = float(values["Force"])
                status[k] = bits
                stroke_used[k] = float(values["StrokeUsed"])
                arrival[k] = now
                shared["next"] = k + 1

    def send(k: int) -> None:
        data, _ = state_enc.encode(Stroke=float(x[k]), Velocity=float(v[k]))
        bus.send(can.Message(arbitration_id=state_enc.frame_id, data=data,
                             is_extended_id=False))

    rx = threading.Thread(target=receive, name="dyno-rx", daemon=True)
    rx.start()
    started = time.monotonic()
    try:
        # 1. connect: the first sample until a force computed from it comes back
        deadline = time.monotonic() + connect_timeout_s
        while not shared["primed"]:
            if time.monotonic() > deadline:
                raise OverCanError(
                    f"no DAMPER_FORCE computed from a DAMPER_STATE within "
                    f"{connect_timeout_s:g} s on {bus_cfg.interface} {bus_cfg.channel} "
                    f"({shared['faults']} fault frames seen: "
                    + ("the bridge runs but no emulator answers)" if shared["faults"]
                       else "is a bridge in dyno mode running?)"))
            send(0)
            time.sleep(0.01)
        # 2. a pause longer than the model's settle gap: the emulator restarts from
        #    quasi-steady equilibrium at the first sample
        time.sleep(settle_gap_s * 1.5 + 0.05)
        shared["recording"] = True
        if progress:
            progress(f"      sending {n} samples at {1.0 / dt:g} Hz over {bus_cfg.interface} "
                     f"{bus_cfg.channel} ({n * dt:.1f} s)")
        counter = [0]
        done = threading.Event()

        def tick(now_ns: int) -> None:
            k = counter[0]
            if k >= n:
                done.set()
                raise StopIteration
            sent_ns[k] = time.monotonic_ns()
            send(k)
            counter[0] = k + 1

        loop = PeriodicLoop(dt, tick, realtime=RealtimeRequest(lock_memory=False, priority=70),
                            name="dyno-tx")
        loop.start()
        while not done.wait(0.5):
            if loop.error is not None and not isinstance(loop.error, StopIteration):
                raise OverCanError(f"dyno send loop failed: {loop.error!r}")
            if not loop.running:
                break
        loop.stop()
        # 3. the last forces
        end = time.monotonic() + drain_timeout_s
        while shared["next"] < n and time.monotonic() < end:
            time.sleep(0.01)
    finally:
        stop.set()
        rx.join(1.0)
        bus.close()
    got = ~np.isnan(force)
    lat = np.where(got, (arrival - sent_ns) * 1e-9, np.nan)
    sent = sent_ns[sent_ns > 0]
    interval_err = float(np.abs(np.diff(sent) * 1e-9 - dt).max()) if sent.size > 1 else 0.0
    mismatch = int(np.sum(got & (np.abs(stroke_used - np.round(x / stroke_step) * stroke_step)
                                 > 1.5 * stroke_step)))
    d = receiver.drops
    return OverCanResult(force, status, stroke_used, lat, sent=int(counter[0]),
                         received=int(got.sum()), fault_frames=int(shared["faults"]),
                         stroke_mismatches=mismatch,
                         dropped={"length": d.length, "checksum": d.checksum,
                                  "counter": d.counter, "lost": d.lost},
                         elapsed_s=time.monotonic() - started,
                         send_interval_error_max_s=interval_err)
