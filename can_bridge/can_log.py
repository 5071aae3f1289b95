"""Raw CAN traffic logged as Vector BLF or ASC, by python-can's own writers
(``--can-log run.blf``; ``can_log`` of the bridge).

:class:`CanLog` takes every frame a :class:`~can_bridge.bus.ResilientBus` sends or
receives, as it passes, and writes it from a thread of its own: the bus's thread (a
real-time loop) only appends a tuple to a queue, never formats, compresses or waits on the
disk.  A received frame keeps the time stamp its interface gave it (the kernel's, for
socketcan and udp_multicast; one on another clock is replaced by the time it is logged),
a sent one is stamped when the bus took it: both on the wall clock (seconds since the
epoch, as python-can stamps frames), marked received or sent (``Rx``/``Tx``), and written
in the order of those stamps (held :data:`REORDER_WINDOW_S` for it).  python-can's
readers (:class:`can.LogReader`), Vector's tools and ``damper-hil replay`` read the files
back.

A BLF file is written in compressed containers: frames reach the disk a container at a
time, and the file is whole once :meth:`CanLog.close` has run (the runs close it on every
way out, Ctrl-C and SIGTERM included).  ASC is text, flushed by the writer thread:
a frame is in the file at most :data:`REORDER_WINDOW_S` + :data:`FLUSH_PERIOD_S` after it
passed.
"""

from __future__ import annotations

import heapq
import math
import queue
import threading
import time
from pathlib import Path

import can

from damper_emulator.errors import UserError, one_line

__all__ = ["SUFFIXES", "CanLog", "CanLogError", "check_log_path"]

#: the file names written, by suffix
SUFFIXES = (".blf", ".asc")
#: the longest an ASC file's frames wait for the disk [s]
FLUSH_PERIOD_S = 0.5
#: frames are written in the order of their time stamps, held this long for it [s]: a
#: received frame is stamped when it arrived, a sent one when it went, and a frame that
#: arrived while this process was answering the one before reaches the log after the
#: answer; python-can's writers take time stamps in order only
REORDER_WINDOW_S = 0.1
#: a received frame's stamp further than this from the wall clock is an interface's own
#: clock (a device's time since its start), not a time: the frame is stamped when logged
STAMP_TOLERANCE_S = 1.0
#: the longest close() waits for the writer thread [s]
CLOSE_TIMEOUT_S = 30.0


class _ASCWriter(can.ASCWriter):
    """python-can's ASC writer with the start's milliseconds written in three digits.
    python-can 4.6.1 writes them unpadded: a start 10 ms into its second is written
    ``.10`` and read back (by python-can's reader, and by CANoe) as 100 ms, every frame's
    time with it, for one start in ten."""

    FORMAT_DATE = "%a %b %d %H:%M:%S.{:03d} %Y"

#: one frame in the queue: stamp [s], identifier, data, extended, remote, received
_Frame = tuple[float, int, bytes, bool, bool, bool]


class CanLogError(UserError):
    """A CAN log that cannot be written (one line: the file, why)."""


def check_log_path(path: str | Path) -> Path:
    """``path`` as a new CAN log's: its suffix one of :data:`SUFFIXES`, and no file there
    (a run never overwrites a recording); checked before a run starts.

    Raises
    ------
    CanLogError
        One line naming the file.
    """
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise CanLogError(f"{path}: a CAN log is .blf (Vector binary) or .asc (Vector "
                          f"text), not '{path.suffix or 'no suffix'}'")
    if path.exists() or path.is_symlink():
        raise CanLogError(f"{path}: exists; a run never overwrites a recording: give a new "
                          f"name")
    return path


class CanLog:
    """A BLF or ASC file of every frame handed to :meth:`add` (module docstring).

    Parameters
    ----------
    path : path-like
        A new ``.blf`` or ``.asc`` file (:func:`check_log_path`); its folder is created.
    channel : int
        The CAN channel number written with each frame (Vector's tools count from 1).

    Attributes
    ----------
    path : Path
    frames : int
        Frames written so far.
    error : str or None
        Why the writer stopped early (one line); frames after it are not written.
    """

    def __init__(self, path: str | Path, channel: int = 1) -> None:
        self.path = check_log_path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise CanLogError(f"{self.path}: cannot create its folder: "
                              f"{exc.strerror or exc}") from None
        self.channel = channel
        self.frames = 0
        self.error: str | None = None
        self._queue: queue.SimpleQueue[_Frame | None] = queue.SimpleQueue()
        try:
            self._writer = (_ASCWriter(self.path) if self.path.suffix.lower() == ".asc"
                            else can.Logger(self.path))
        except (OSError, ValueError) as exc:
            raise CanLogError(f"{self.path}: cannot write the CAN log: "
                              f"{one_line(exc)}") from None
        self._closed = False
        self._last = -math.inf
        self._thread = threading.Thread(target=self._run, name="can-log", daemon=True)
        self._thread.start()

    def add(self, msg: can.Message, received: bool) -> None:
        """Log ``msg`` (``received``: from the bus; else sent by this process).  Cheap and
        never blocking: the frame is copied into a queue the writer thread empties."""
        now = time.time()
        stamp = float(msg.timestamp) if received and msg.timestamp else now
        if not abs(stamp - now) < STAMP_TOLERANCE_S:    # an interface's own clock
            stamp = now
        self._queue.put((stamp, msg.arbitration_id, bytes(msg.data), msg.is_extended_id,
                         msg.is_remote_frame, received))

    def _run(self) -> None:
        text = self.path.suffix.lower() == ".asc"
        next_flush = time.monotonic() + FLUSH_PERIOD_S
        held: list[tuple[float, int, _Frame]] = []   # a heap: by time stamp, then arrival
        order = 0
        while True:
            try:
                item = self._queue.get(timeout=REORDER_WINDOW_S)
            except queue.Empty:
                pass                       # nothing came: write what is due, flush
            else:
                if item is None:
                    break
                heapq.heappush(held, (item[0], order, item))
                order += 1
            due = time.time() - REORDER_WINDOW_S
            while held and held[0][0] <= due:
                self._write(heapq.heappop(held)[2])
            if text and time.monotonic() >= next_flush:
                next_flush = time.monotonic() + FLUSH_PERIOD_S
                self._flush()
        while held:
            self._write(heapq.heappop(held)[2])

    def _write(self, item: _Frame) -> None:
        if self.error is not None:
            return
        stamp, frame_id, data, extended, remote, received = item
        # in time order: a frame that comes later than the window is written at the last
        # time written (python-can's writers take the file's start from its first frame)
        stamp = self._last = max(stamp, self._last)
        try:
            self._writer.on_message_received(can.Message(
                timestamp=stamp, arbitration_id=frame_id, data=data, is_extended_id=extended,
                is_remote_frame=remote, is_rx=received, channel=self.channel, dlc=len(data)))
        except Exception as exc:  # noqa: BLE001 - python-can's writers raise what they meet
            self.error = f"{self.path}: the CAN log stopped: {one_line(exc, with_type=True)}"
            return
        self.frames += 1

    def _flush(self) -> None:
        file = getattr(self._writer, "file", None)
        if file is not None and self.error is None:
            try:
                file.flush()
            except (OSError, ValueError) as exc:
                self.error = f"{self.path}: the CAN log stopped: {one_line(exc)}"

    def close(self) -> None:
        """Write what is queued and close the file (idempotent).

        Raises
        ------
        CanLogError
            The file could not be written whole (one line).
        """
        if self._closed:
            return
        self._closed = True
        self._queue.put(None)
        self._thread.join(CLOSE_TIMEOUT_S)
        try:
            self._writer.stop()
        except (OSError, ValueError) as exc:
            self.error = self.error or f"{self.path}: closing the CAN log: {one_line(exc)}"
        if self.error is not None:
            raise CanLogError(self.error)

    def __enter__(self) -> CanLog:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
