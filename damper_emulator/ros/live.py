"""The live view: the damper and the ride as they run, in Foxglove or Lichtblick,
through the Foxglove SDK's WebSocket server (``foxglove-sdk``, optional).

:class:`LiveServer` serves, on ``ws://127.0.0.1:PORT`` (localhost only), three JSON channels
(:data:`CHANNELS`, each with its JSON schema):

* ``/live/damper``: stroke, velocity, force and status bits of the emulator's outputs (the
  F–v loop and F(t));
* ``/live/ride``: SWS, body acceleration and tyre load, and their r.m.s. values as they
  accumulate (body acceleration ISO 2631-1 Wk-weighted);
* ``/live/loop``: the emulator loop's figures (achieved rate, period p99, period error p99,
  overruns, status), also as the server's status message.

Two users: the ``live_view`` node (:mod:`damper_hil.live_node`, ``damper-hil live``,
``demo --live``), a process of its own that feeds all three from the topics; and the
emulator itself with ``emulator.live_port`` (``/live/damper`` and ``/live/loop`` only, from
its executor thread, never from its loop).  ``config/foxglove_layout.json`` lays the panels
out.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

from damper_emulator.errors import UserError

#: SCHED_FIFO priority (when permitted) of the view's threads (its flush timer, the DDS and
#: WebSocket threads); 0: normal scheduling.  Above every normally scheduled process, so
#: that a busy machine does not freeze the view (under two CPU hogs on a two-core machine
#: its flushes came seconds apart, and a loaded one sent no ride message at all), and
#: below the recorder's (50), the bridge's and the loops', so that
#: the view never delays what is recorded or emulated.
LIVE_PRIORITY = 10

#: the channels: topic → (schema name, {field: (JSON type, description)})
CHANNELS: dict[str, tuple[str, dict[str, tuple[str, str]]]] = {
    "/live/damper": ("damper_hil.LiveDamper", {
        "t": ("number", "time since the view started [s]"),
        "stroke_m": ("number", "stroke of the input used [m, extension +]"),
        "velocity_m_s": ("number", "velocity of the input used [m/s]"),
        "force_n": ("number", "damper force [N, rebound +]"),
        "status": ("integer", "emulator status bits (docs/interfaces.md)")}),
    "/live/ride": ("damper_hil.LiveRide", {
        "t": ("number", "time since the view started [s]"),
        "sws_m": ("number", "suspension working space z1 - z2 [m]"),
        "body_accel_m_s2": ("number", "body acceleration [m/s^2]"),
        "dtl_n": ("number", "dynamic tyre load [N]"),
        "accel_w_rms_m_s2": ("number", "Wk-weighted body acceleration r.m.s. so far [m/s^2]"),
        "sws_rms_m": ("number", "SWS r.m.s. so far [m]"),
        "dtl_rms_n": ("number", "dynamic tyre load r.m.s. so far [N]"),
        "samples": ("integer", "ride samples so far")}),
    "/live/loop": ("damper_hil.LiveLoop", {
        "t": ("number", "time since the view started [s]"),
        "achieved_rate_hz": ("number", "the emulator loop's rate [Hz]"),
        "period_p99_us": ("number", "loop period p99 [us]"),
        "period_error_p99_us": ("number", "loop period error p99 [us]"),
        "overruns": ("integer", "loop overruns so far"),
        "level": ("integer", "diagnostic level (0 ok, 1 warn, 2 error)"),
        "message": ("string", "the emulator's diagnostic message")}),
}
#: where the server listens: this machine only
HOST = "127.0.0.1"


def json_schema(fields: dict[str, tuple[str, str]]) -> dict[str, Any]:
    return {"type": "object", "properties": {
        k: {"type": kind, "description": doc} for k, (kind, doc) in fields.items()}}


def require_sdk() -> None:
    """Raise a one-line :class:`UserError` when the Foxglove SDK is not installed."""
    try:
        import foxglove  # noqa: F401
    except ImportError:
        raise UserError("the live view needs the Foxglove SDK: pip install foxglove-sdk "
                        "(or the project's 'live' extra)") from None


def diagnostic_level(level: int | bytes) -> int:
    """A ``DiagnosticStatus`` level as an int (rclpy gives it as one byte)."""
    return int.from_bytes(level, "little") if isinstance(level, bytes) else int(level)


def loop_message(t: float, values: dict[str, str], level: int, message: str
                 ) -> dict[str, Any]:
    """The ``/live/loop`` message from the emulator's ``/diagnostics`` key/values."""
    def number(key: str, default: float = math.nan) -> float:
        try:
            text = values.get(key)
            return float(text) if text not in (None, "") else default
        except ValueError:
            return default

    return {"t": t, "achieved_rate_hz": number("achieved_rate_hz"),
            "period_p99_us": number("period_p99_us"),
            "period_error_p99_us": number("period_error_p99_us"),
            "overruns": int(number("overruns", 0.0)), "level": level, "message": message}


class LiveServer:
    """The Foxglove WebSocket server and its channels (:data:`CHANNELS`)."""

    def __init__(self, port: int, name: str = "damper-hil") -> None:
        require_sdk()
        import foxglove

        try:
            self.server = foxglove.start_server(name=name, host=HOST, port=port)
        except Exception as exc:  # noqa: BLE001 - the SDK's own error type: a port in use, ...
            raise UserError(f"live view: cannot serve on {HOST}:{port} ({exc})") from None
        self.channels = {topic: foxglove.Channel(topic, message_encoding="json",
                                                 schema=foxglove.Schema(
                                                     name=name, encoding="jsonschema",
                                                     data=json.dumps(json_schema(fields))
                                                     .encode()))
                         for topic, (name, fields) in CHANNELS.items()}
        self.started = time.monotonic()

    @property
    def port(self) -> int:
        return int(self.server.port)

    def damper(self, out_force_n: float, stroke_m: float, velocity_m_s: float,
               status: int) -> None:
        """One ``/live/damper`` message."""
        self.log("/live/damper", {"t": time.monotonic() - self.started, "stroke_m": stroke_m,
                                  "velocity_m_s": velocity_m_s, "force_n": out_force_n,
                                  "status": status})

    def loop(self, values: dict[str, str], level: int | bytes, name: str,
             message: str) -> None:
        """One ``/live/loop`` message and the status line, from a ``/diagnostics`` status
        (``level`` as rclpy gives it: one byte)."""
        level = diagnostic_level(level)
        self.log("/live/loop", loop_message(time.monotonic() - self.started, values, level,
                                            message))
        self.status(f"{name}: {message}", level)

    def log(self, topic: str, message: dict[str, Any]) -> None:
        """Send ``message`` on ``topic``; a value that is not a finite number goes as null
        (JSON has no NaN)."""
        self.channels[topic].log({k: (None if isinstance(v, float) and not math.isfinite(v)
                                      else v) for k, v in message.items()})

    def status(self, text: str, level: int) -> None:
        import foxglove

        levels = (foxglove.StatusLevel.Info, foxglove.StatusLevel.Warning,
                  foxglove.StatusLevel.Error)
        self.server.publish_status(text, levels[min(max(level, 0), 2)], id="emulator")

    def stop(self) -> None:
        self.server.stop()
