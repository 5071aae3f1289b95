"""The bridge's logic without ROS or a bus: CAN frames (config/damper.dbc) ↔ damper samples,
timeouts and status bits.  :mod:`can_bridge.node` is the rclpy shell around it.

``mode: dyno``
    ``DAMPER_STATE`` frames become damper samples (:meth:`BridgeCore.on_frame`); each force
    of the emulator becomes one ``DAMPER_FORCE`` frame (:meth:`BridgeCore.force_frame`).
``mode: controller``
    ``VALVE_COMMAND`` frames become valve commands; the simulation's motion becomes
    ``VEHICLE_MOTION`` frames at the DBC cycle (:meth:`BridgeCore.motion_frame`); forces
    become ``DAMPER_FORCE`` frames (status for the controller).

In both modes :meth:`BridgeCore.watchdog` sends ``DAMPER_FORCE`` frames with
:attr:`ForceStatus.FORCE_TIMEOUT` at the DBC cycle while the emulator is silent, and, in
controller mode, falls back to ``fail_safe_command`` while the controller is silent.  Frames
with a wrong length, checksum or a counter that did not advance are dropped and counted by
the :class:`~can_bridge.codec.Receiver`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from can_bridge.codec import Encoder, Receiver
from can_bridge.dbc import ForceStatus, cycle_time_s, raw_range
from can_bridge.settings import BridgeParams

STATE, FORCE, COMMAND, MOTION = "DAMPER_STATE", "DAMPER_FORCE", "VALVE_COMMAND", "VEHICLE_MOTION"
#: ``InputAge`` value meaning unknown or beyond the signal's range.
INPUT_AGE_UNKNOWN_S = 0.0255
#: A ``VEHICLE_MOTION`` frame is due this fraction of its DBC cycle after the last one:
#: states arrive on a 1 ms grid with jitter, and a frame due at exactly one cycle would
#: slip a state late half the time.
MOTION_CYCLE_TOLERANCE = 0.95


@dataclass
class BridgeCounters:
    """What the bridge did, for ``/diagnostics``."""

    states_in: int = 0          # DAMPER_STATE frames turned into samples
    commands_in: int = 0        # VALVE_COMMAND frames turned into commands
    forces_out: int = 0         # DAMPER_FORCE frames from emulator forces
    fault_frames_out: int = 0   # DAMPER_FORCE frames sent by the watchdog
    motion_out: int = 0         # VEHICLE_MOTION frames
    state_timeouts: int = 0     # times the DAMPER_STATE stream went silent
    force_timeouts: int = 0     # times /damper/force went silent
    command_timeouts: int = 0   # times the controller went silent (fail-safe applied)
    saturated: int = 0          # forces beyond the signal's range


class BridgeCore:
    """See the module docstring.

    Parameters
    ----------
    params : BridgeParams
    db : cantools.database.Database
        The CAN database (:func:`can_bridge.dbc.load_database`).
    """

    def __init__(self, params: BridgeParams, db):
        self.params = params
        self.counters = BridgeCounters()
        inbound = STATE if params.mode == "dyno" else COMMAND
        self.receiver = Receiver(db, [inbound])
        self.force_encoder = Encoder(db, FORCE)
        self.motion_encoder = Encoder(db, MOTION)
        force = db.get_message_by_name(FORCE).get_signal_by_name("Force")
        # the range the encoder saturates Force to: the DBC's [min|max] on the raw grid, or
        # the raw type's where the DBC gives none
        lo, hi = (v * force.scale + force.offset for v in raw_range(force))
        self._force_lo, self._force_hi = min(lo, hi), max(lo, hi)
        self.force_cycle_ns = int(cycle_time_s(db.get_message_by_name(FORCE)) * 1e9)
        self.motion_cycle_ns = int(cycle_time_s(db.get_message_by_name(MOTION)) * 1e9)
        self._last_in_ns: int | None = None      # last accepted inbound frame
        self._last_force_ns: int | None = None   # last emulator force
        #: monotonic time [ns] of the watchdog's next fault frame while the emulator is
        #: silent (the receive loop waits at most until then)
        self.next_watchdog_ns = 0
        self._last_motion_ns: int | None = None
        self._state_silent = False
        self._force_silent = False
        self._command_silent = False
        self._rx_trouble = False
        self._drops_seen = 0
        self.command: float | None = None        # controller: latest valve command

    @property
    def fault_active(self) -> bool:
        return bool(self.fault_text)

    @property
    def fault_text(self) -> str:
        """What is silent now ('' when nothing is)."""
        parts = []
        if self._state_silent:
            parts.append("no DAMPER_STATE frames")
        if self._force_silent:
            parts.append("no /damper/force")
        if self._command_silent:
            parts.append("no VALVE_COMMAND frames (fail-safe command)")
        return "; ".join(parts)

    # ---- inbound ----------------------------------------------------------------------

    def on_frame(self, frame_id: int, data: bytes, now_ns: int):
        """An inbound frame: ``("state", stroke_m, velocity_m_s)``, ``("command", value)``
        or None (another message, or dropped and counted by :attr:`receiver`)."""
        got = self.receiver.accept(frame_id, bytes(data))
        self._note_drops()
        if got is None:
            return None
        name, values = got
        self._last_in_ns = now_ns
        if name == STATE:
            self._state_silent = False
            self.counters.states_in += 1
            return ("state", float(values["Stroke"]), float(values["Velocity"]))
        self._command_silent = False
        self.counters.commands_in += 1
        self.command = min(max(float(values["Command"]), 0.0), 1.0)
        return ("command", self.command)

    def note_rx_errors(self) -> None:
        """The bus reported receive errors: flag the next DAMPER_FORCE frame."""
        self._rx_trouble = True

    def _note_drops(self) -> None:
        d = self.receiver.drops
        dropped = d.dropped + d.lost
        if dropped != self._drops_seen:
            self._drops_seen = dropped
            self._rx_trouble = True

    # ---- outbound ---------------------------------------------------------------------

    def _inbound_status(self, now_ns: int) -> ForceStatus:
        bits = ForceStatus(0)
        if self.params.mode == "dyno":
            timeout_ns = self.params.state_timeout_s * 1e9
            if self._last_in_ns is None or now_ns - self._last_in_ns > timeout_ns:
                if not self._state_silent and self._last_in_ns is not None:
                    self.counters.state_timeouts += 1
                self._state_silent = True
                bits |= ForceStatus.CAN_STATE_TIMEOUT
        if self._rx_trouble:
            bits |= ForceStatus.CAN_RX_ERRORS
            self._rx_trouble = False
        return bits

    def force_frame(self, force_n: float, status: int, input_age_s: float, stroke_m: float,
                    now_ns: int) -> bytes:
        """The ``DAMPER_FORCE`` payload for one emulator force (``status``: the emulator's
        bits; ``input_age_s``, ``stroke_m`` of the input it used, NaN when none)."""
        self._last_force_ns = now_ns
        self._force_silent = False
        self.counters.forces_out += 1
        bits = int(status) | int(self._inbound_status(now_ns))
        return self._encode_force(force_n, bits, input_age_s, stroke_m)

    def _encode_force(self, force_n: float, bits: int, input_age_s: float,
                      stroke_m: float) -> bytes:
        # NaN: no force to send (0 N); ±inf is beyond the range: saturated and flagged
        force = 0.0 if math.isnan(force_n) else force_n
        if not self._force_lo <= force <= self._force_hi:
            self.counters.saturated += 1
            bits |= int(ForceStatus.FORCE_SATURATED)
            force = min(max(force, self._force_lo), self._force_hi)
        age = input_age_s if math.isfinite(input_age_s) and input_age_s >= 0 else \
            INPUT_AGE_UNKNOWN_S
        data, _ = self.force_encoder.encode(
            Force=force, Status=bits, InputAge=min(age, INPUT_AGE_UNKNOWN_S),
            StrokeUsed=stroke_m if math.isfinite(stroke_m) else 0.0)
        return data

    def fault_frame(self, now_ns: int) -> bytes:
        """A ``DAMPER_FORCE`` fault payload: 0 N with Status bit 32 (no force from the
        emulator) and the inbound bits; the watchdog's, and the bridge's last frame when it
        leaves 'active'."""
        self.counters.fault_frames_out += 1
        bits = int(ForceStatus.FORCE_TIMEOUT) | int(self._inbound_status(now_ns))
        return self._encode_force(0.0, bits, math.nan, math.nan)

    def watchdog_wait_ns(self, now_ns: int) -> int:
        """How long the receive loop may wait for a frame before :meth:`watchdog` is due:
        until the next fault frame while the emulator is silent, else one DBC cycle."""
        if not self._force_silent:
            return self.force_cycle_ns
        return min(self.force_cycle_ns, max(0, self.next_watchdog_ns - now_ns))

    def watchdog(self, now_ns: int) -> tuple[bytes | None, float | None]:
        """Call often (at least every DBC cycle).  Returns ``(fault DAMPER_FORCE payload or
        None, fail-safe valve command to apply or None)``."""
        frame = None
        timeout_ns = self.params.force_timeout_s * 1e9
        since = None if self._last_force_ns is None else now_ns - self._last_force_ns
        if since is None or since > timeout_ns:
            if not self._force_silent and since is not None:
                self.counters.force_timeouts += 1
            self._force_silent = True
            if now_ns >= self.next_watchdog_ns:
                # paced on deadlines (one DBC cycle apart), not on the calls: no drift
                self.next_watchdog_ns += self.force_cycle_ns
                if now_ns >= self.next_watchdog_ns:        # fell behind: no burst
                    self.next_watchdog_ns = now_ns + self.force_cycle_ns
                frame = self.fault_frame(now_ns)
        command = None
        if self.params.mode == "controller" and not self._command_silent:
            c_timeout_ns = self.params.command_timeout_s * 1e9
            if self._last_in_ns is not None and now_ns - self._last_in_ns > c_timeout_ns:
                self._command_silent = True
                self.counters.command_timeouts += 1
                self.command = self.params.fail_safe_command
                command = self.command
        return frame, command

    def motion_due(self, now_ns: int) -> bool:
        """Whether a DBC cycle has passed since the last ``VEHICLE_MOTION`` frame."""
        return self._last_motion_ns is None or \
            now_ns - self._last_motion_ns >= self.motion_cycle_ns * MOTION_CYCLE_TOLERANCE

    def motion_wait_ns(self, now_ns: int) -> int:
        """How long until the next ``VEHICLE_MOTION`` frame is due [ns] (0: now)."""
        if self._last_motion_ns is None:
            return 0
        due = self._last_motion_ns + int(self.motion_cycle_ns * MOTION_CYCLE_TOLERANCE)
        return max(0, due - now_ns)

    def motion_frame(self, body_velocity_m_s: float, wheel_velocity_m_s: float,
                     damper_velocity_m_s: float, now_ns: int) -> bytes | None:
        """The ``VEHICLE_MOTION`` payload when it is due (:meth:`motion_due`), else None
        (the simulation's state arrives faster than the message's cycle)."""
        if not self.motion_due(now_ns):
            return None
        self._last_motion_ns = now_ns
        self.counters.motion_out += 1
        data, _ = self.motion_encoder.encode(BodyVelocity=body_velocity_m_s,
                                             WheelVelocity=wheel_velocity_m_s,
                                             DamperVelocity=damper_velocity_m_s)
        return data
