"""The live view (issue 18): the damper and the ride as they run, in Foxglove or Lichtblick,
through the Foxglove SDK's WebSocket server (``foxglove-sdk``, optional).

``damper-hil live`` (and ``damper-hil demo --live``) runs :class:`LiveNode`, a plain ROS 2
node in a process of its own: it subscribes to ``/damper/force``, ``/ride/state`` and
``/diagnostics`` and serves, on ``ws://127.0.0.1:PORT`` (localhost only), three JSON
channels (:data:`CHANNELS`, each with its JSON schema):

* ``/live/damper``: stroke, velocity and force of every ``decimation``-th force sample,
  with its status bits (the F–v loop and F(t));
* ``/live/ride``: SWS, body acceleration and tyre load, and their r.m.s. values as they
  accumulate (body acceleration ISO 2631-1 Wk-weighted, the ride study's filter run on the
  stream), at ``ride_rate_hz``;
* ``/live/loop``: the emulator's loop figures from its ``/diagnostics`` (achieved rate,
  period p99, period error p99, overruns, status), once per diagnostics period; the same
  status line also as the server's status message.

It touches no real-time loop: the emulator and the ride do not know it exists (one more
DDS subscriber, measured in the README).  ``config/foxglove_layout.json`` lays the panels
out (force against velocity, force against time, the ride metrics, the status).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from damper_emulator.errors import UserError

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


class RunningRms:
    """r.m.s. of a stream, from its sum of squares."""

    def __init__(self) -> None:
        self.n = 0
        self.sum_sq = 0.0

    def add(self, x: np.ndarray) -> None:
        self.n += x.size
        self.sum_sq += float(np.dot(x, x))

    @property
    def value(self) -> float:
        return math.sqrt(self.sum_sq / self.n) if self.n else 0.0


class LiveServer:
    """The Foxglove WebSocket server and its channels (:data:`CHANNELS`)."""

    def __init__(self, port: int, name: str = "damper-hil") -> None:
        try:
            import foxglove
        except ImportError:
            raise UserError("the live view needs the Foxglove SDK: pip install foxglove-sdk "
                            "(or the project's 'live' extra)") from None
        try:
            self.server = foxglove.start_server(name=name, host=HOST, port=port)
        except Exception as exc:  # the SDK's own error type: a port in use, ...
            raise UserError(f"live view: cannot serve on {HOST}:{port} ({exc})") from None
        self.channels = {topic: foxglove.Channel(topic, schema=json_schema(fields))
                         for topic, (_, fields) in CHANNELS.items()}
        self.started = time.monotonic()

    @property
    def port(self) -> int:
        return int(self.server.port)

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
