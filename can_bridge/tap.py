"""A listener on a CAN bus: every frame with the time it arrived.

:class:`BusTap` reads a bus on a thread of its own and keeps ``(arrival, id, payload)``
of every data frame, the arrival on ``time.monotonic``'s clock from the kernel's receive
stamp where the interface gives one (:func:`can_bridge.bus.receive_time`): what went over
the wire and when, for a test or a benchmark that checks timing (e.g. how soon ``Enable``
was cleared after the last feedback).
"""

from __future__ import annotations

import threading
import time

from can_bridge.bus import BusConfig, ResilientBus, receive_time


class BusTap:
    """Records the frames of ``cfg``'s bus until :meth:`close`."""

    def __init__(self, cfg: BusConfig) -> None:
        self.bus = ResilientBus(cfg)
        if not self.bus.ensure_open():
            raise RuntimeError(self.bus.last_error or f"cannot open {cfg.label}")
        self.frames: list[tuple[float, int, bytes]] = []
        self._offset = time.time() - time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="can-tap", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is not None:
                self.frames.append((receive_time(msg, self._offset), msg.arbitration_id,
                                    bytes(msg.data)))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.close()
