"""The record of a damper-in-the-loop ride, written while it runs.

:class:`HybridRecorder` hands the ride's completed samples, every ``period_s``, to a
:class:`RecordWriter` that appends them to ``hybrid.csv`` and to a rosbag2 bag (MCAP,
crash-safe :class:`~damper_emulator.bag.BagWriter`).  The writer runs in a process of its
own (``in_process=False``, the real-time runs): formatting and the bag's chunks never take
Python's GIL from the loop, and when the host process dies the writer reads the end of its
pipe and closes both files, whole up to the last samples handed over.

``hybrid.csv`` columns: ``t_monotonic_ns`` (the host's CLOCK_MONOTONIC when the sample's
command was sent), ``time`` [s, from the ride's start], ``stroke_target``,
``stroke_command``, ``stroke_measured`` [m], ``force_measured``, ``force_model`` [N],
``enable`` (0/1).  The bag's topics (:data:`TOPICS`), stamped with ``t_monotonic_ns``:

* ``/damper/state`` (``sensor_msgs/msg/JointState``): the measured stroke and its velocity
  (backward difference), as the emulator's input is recorded: a recorded ride replays and
  reads as measured data;
* ``/damper/force`` (``JointState``): the measured force in ``effort[0]``, with the motion;
* ``/hybrid/loop`` (``JointState``, joints ``target``, ``command``, ``twin``): the car's
  damper stroke, the demand sent and the measured stroke (``position``), and the twin's
  force on the measured motion (``effort[2]``);
* ``/diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``), once per ``diagnostics_s``:
  the twin's residual r.m.s., the tracking NRMS and the rig's delay as followed
  (:func:`loop_status`).
"""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import IO, Any

import numpy as np

from damper_emulator.bag import BagWriter, Topic
from damper_emulator.bag.cdr_fast import encode_joint_states, rows_to_bytes
from damper_emulator.bag.messages import DIAGNOSTIC_ARRAY, JOINT_STATE, diagnostic_array
from damper_emulator.errors import DamperHilError
from damper_emulator.topics import DIAGNOSTICS, FORCE, HYBRID_LOOP, STATE
from ride_sim.hybrid.host import RECORD_COLUMNS, HybridHost
from ride_sim.hybrid.rig_host import LATE_CYCLES

#: hybrid.csv's header
CSV_COLUMNS = ("t_monotonic_ns", "time", *RECORD_COLUMNS)
#: one hybrid.csv row
ROW_FORMAT = "%d,%.6f,%.9g,%.9g,%.9g,%.9g,%.9g,%d\n"
#: the bag's topics and their types
TOPICS = {STATE: JOINT_STATE, FORCE: JOINT_STATE, HYBRID_LOOP: JOINT_STATE,
          DIAGNOSTICS: DIAGNOSTIC_ARRAY}
#: the joint of ``/damper/state`` and ``/damper/force``; the joints of ``/hybrid/loop``
JOINT = "damper"
LOOP_JOINTS = ("target", "command", "twin")
#: the longest the writer process may take to start [s]
WRITER_START_TIMEOUT_S = 60.0
#: the DiagnosticStatus name of the run
DIAGNOSTIC_NAME = "damper_hil: hybrid"


class RecorderError(DamperHilError, RuntimeError):
    """The record could not be written (one line: why)."""


@dataclass(frozen=True)
class Chunk:
    """Completed samples ``[start, start + n)`` of the ride, and the run's state then."""

    start: int
    t_ns: np.ndarray          # (n,)
    record: np.ndarray        # (len(RECORD_COLUMNS), n)
    delay_s: float            # the rig's delay as followed, at the chunk's end
    phase: str
    reason: str | None


def loop_status(record: np.ndarray, delay_s: float, phase: str, reason: str | None
                ) -> tuple[int, str, list[tuple[str, str]]]:
    """``(level, message, values)`` of the samples ``record`` (a window of the ride): the
    twin's residual r.m.s., the tracking error over the target's r.m.s., the rig's delay as
    followed.  Level 0 (OK) unless the run has stopped (2)."""
    residual = record[3] - record[4]
    residual = residual[np.isfinite(residual)]
    twin_rms = float(np.sqrt(np.mean(residual ** 2))) if residual.size else math.nan
    target = record[0]
    scale = float(np.sqrt(np.mean(target ** 2))) if target.size else math.nan
    error = record[2] - target
    nrms = float(np.sqrt(np.mean(error ** 2))) / scale if scale > 0 else math.nan
    values = [("twin_residual_rms_n", f"{twin_rms:.6g}"), ("tracking_nrms", f"{nrms:.6g}"),
              ("delay_ms", f"{delay_s * 1e3:.6g}"), ("phase", phase)]
    level = 2 if phase == "stopped" else 0
    return level, reason or f"twin residual {twin_rms:.1f} N r.m.s.", values


class RecordWriter:
    """Appends chunks to ``hybrid.csv`` and the bag (one process, one thread).

    Parameters
    ----------
    out : Path
        The run's directory (exists).
    dt_s : float
        The cycle [s].
    bag : bool
        Write the bag (``out/bag``) too.
    diagnostics_s : float
        The ``/diagnostics`` period and window [s].
    """

    def __init__(self, out: Path, dt_s: float, *, bag: bool = True,
                 diagnostics_s: float = 1.0) -> None:
        self.dt_s = float(dt_s)
        self._window = max(1, int(round(diagnostics_s / dt_s)))
        self._csv: IO[str] = open(  # noqa: SIM115 (the writer holds it until close())
            Path(out) / "hybrid.csv", "w", encoding="utf-8", newline="\n")
        self._csv.write(",".join(CSV_COLUMNS) + "\n")
        self._csv.flush()
        self._bag: BagWriter | None = None
        self._topics: dict[str, Topic] = {}
        if bag:
            self._bag = BagWriter(Path(out) / "bag", custom_data={"damper_hil": "hybrid"})
            self._topics = {name: self._bag.add_topic(name, msgtype)
                            for name, msgtype in TOPICS.items()}
        self._recent = np.zeros((len(RECORD_COLUMNS), 0))
        self._next_diag = self._window
        self._prev_x = math.nan
        self._last_stamp = 0

    def write(self, chunk: Chunk) -> None:
        n = chunk.t_ns.size
        if n == 0:
            return
        rec = chunk.record
        time_s = np.arange(chunk.start, chunk.start + n) * self.dt_s
        enable = np.nan_to_num(rec[5], nan=0.0).astype(int)
        rows = zip(chunk.t_ns.tolist(), time_s.tolist(), *rec[:5].tolist(), enable.tolist())
        self._csv.write("".join([ROW_FORMAT % row for row in rows]))
        self._csv.flush()
        if self._bag is not None:
            self._write_bag(chunk)

    def close(self) -> None:
        try:
            self._csv.close()
        finally:
            if self._bag is not None:
                self._bag.close()

    def _stamps(self, t_ns: np.ndarray) -> np.ndarray:
        """The samples' stamps: their send times, a sample never stamped (none sent) one
        cycle after the one before; never decreasing."""
        dt_ns = int(round(self.dt_s * 1e9))
        out = np.array(t_ns, dtype=np.int64)
        last = self._last_stamp
        for i in range(out.size):
            if out[i] <= last:
                out[i] = last + (dt_ns if out[i] == 0 else 1)
            last = int(out[i])
        self._last_stamp = last
        return out

    def _write_bag(self, chunk: Chunk) -> None:
        bag = self._bag
        assert bag is not None
        rec = chunk.record
        n = chunk.t_ns.size
        x = rec[2]
        previous = np.concatenate([[self._prev_x if math.isfinite(self._prev_x) else x[0]],
                                   x[:-1]])
        v = (x - previous) / self.dt_s
        self._prev_x = float(x[-1])
        empty = np.zeros((n, 0))
        zero = np.zeros(n)
        col = np.column_stack
        messages: dict[str, tuple[Sequence[str], np.ndarray, np.ndarray, np.ndarray]] = {
            STATE: ([JOINT], col([x]), col([v]), empty),
            FORCE: ([JOINT], col([x]), col([v]), col([rec[3]])),
            HYBRID_LOOP: (list(LOOP_JOINTS), col([rec[0], rec[1], x]), empty,
                          col([zero, zero, np.nan_to_num(rec[4], nan=0.0)])),
        }
        stamps = self._stamps(chunk.t_ns)
        encoded = [(self._topics[name], rows_to_bytes(
            encode_joint_states(stamps, names, pos, vel, eff)))
            for name, (names, pos, vel, eff) in messages.items()]
        for i, stamp in enumerate(stamps.tolist()):      # in time order, all topics
            for topic, data in encoded:
                bag.write(topic, stamp, data[i])
        self._recent = np.concatenate([self._recent, rec], axis=1)[:, -self._window:]
        end = chunk.start + n
        while self._next_diag <= end:
            level, message, values = loop_status(self._recent, chunk.delay_s, chunk.phase,
                                                 chunk.reason)
            stamp = int(stamps[-1])          # written after the chunk: its last stamp
            bag.write(self._topics[DIAGNOSTICS], stamp,
                      diagnostic_array(stamp, [(level, DIAGNOSTIC_NAME, message, JOINT,
                                                values)]))
            self._next_diag += self._window


def _writer_main(conn: Connection, out: str, dt_s: float, bag: bool) -> None:
    """The writer process: says ``"ready"`` once its files are open, then writes the
    chunks from ``conn`` until ``None`` or the end of the pipe (the host died), then closes
    both files.  SIGINT is the host's to handle: the writer ends with the host's pipe."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        writer = RecordWriter(Path(out), dt_s, bag=bag)
        diagnostic_array(0, [(0, DIAGNOSTIC_NAME, "", JOINT, [])])   # load the codec now
    except BaseException as exc:
        conn.send(f"{type(exc).__name__}: {exc}")
        raise
    conn.send("ready")
    try:
        while True:
            try:
                chunk = conn.recv()
            except EOFError:
                break
            if chunk is None:
                break
            writer.write(chunk)
    finally:
        writer.close()


class WriterProcess:
    """The writer process of a run (:func:`_writer_main`), started ahead of the host: its
    imports and the bag's codec load while the host builds its reference run and warms
    up.  :meth:`ready` waits until its files are open; :meth:`close` ends it (idempotent).
    ``out``, ``dt_s`` and ``bag`` are the :class:`RecordWriter`'s it runs.
    """

    def __init__(self, out: Path, dt_s: float, bag: bool = True) -> None:
        ctx = multiprocessing.get_context("spawn")
        ours, theirs = ctx.Pipe(duplex=True)
        self.process: Any = ctx.Process(target=_writer_main, name="hybrid-writer",
                                        args=(theirs, str(out), float(dt_s), bag),
                                        daemon=False)
        self.process.start()
        theirs.close()
        self.conn: Connection | None = ours

    def ready(self) -> None:
        """Wait until the writer has opened its files.

        Raises
        ------
        RecorderError
            It did not start within :data:`WRITER_START_TIMEOUT_S`, or could not open them.
        """
        conn = self.conn
        assert conn is not None
        if not conn.poll(WRITER_START_TIMEOUT_S):
            self.close()
            raise RecorderError(f"the record's writer did not start within "
                                f"{WRITER_START_TIMEOUT_S:g} s")
        try:
            answer = conn.recv()
        except EOFError:
            answer = "it ended"
        if answer != "ready":
            self.close()
            raise RecorderError(f"the record's writer could not start: {answer}")

    def send(self, chunk: Chunk) -> None:
        """Hand ``chunk`` over to be written."""
        if not self.process.is_alive():
            raise RecorderError(f"the record's writer process ended (status "
                                f"{self.process.exitcode}) during the run")
        assert self.conn is not None
        self.conn.send(chunk)

    def close(self) -> int:
        """Tell the writer the run is over, wait for it to close its files; its exit
        status."""
        if self.conn is not None:
            with contextlib.suppress(OSError):      # the writer has gone already
                self.conn.send(None)
            self.conn.close()
            self.conn = None
        self.process.join()
        return int(self.process.exitcode)


class HybridRecorder:
    """Hands ``host``'s completed samples to a :class:`RecordWriter` every ``period_s``.

    Parameters
    ----------
    out : Path
        The run's directory (exists).
    host : HybridHost
    bag : bool
        Write the bag (``out/bag``) too.
    period_s : float
        How often the completed samples go to the writer [s].
    in_process : bool
        Write in this process's thread (offline runs, tests) instead of a writer process.
    on_status : callable, optional
        Called from the recorder's thread once per ``diagnostics_s`` with
        :func:`loop_status`'s ``(level, message, values)`` over that window: the live
        ``/diagnostics`` of ``damper-hil hybrid --ros``.
    diagnostics_s : float
        The window of ``on_status`` [s].
    writer : WriterProcess, optional
        The writer process, started earlier (default: started on entering); the recorder
        closes it.
    """

    def __init__(self, out: Path, host: HybridHost, *, bag: bool = True,
                 period_s: float = 0.1, in_process: bool = False,
                 on_status: Callable[[int, str, list[tuple[str, str]]], None] | None = None,
                 diagnostics_s: float = 1.0, writer: WriterProcess | None = None) -> None:
        self.out = Path(out)
        self.host = host
        self.csv_path = self.out / "hybrid.csv"
        self.bag_path = self.out / "bag" if bag else None
        self._bag = bag
        self._period = float(period_s)
        self._in_process = in_process
        self._written = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._writer: RecordWriter | None = None
        self._process: WriterProcess | None = writer
        self.error: BaseException | None = None
        self._on_status = on_status
        self._status_window = max(1, int(round(diagnostics_s / host.dt_s)))
        self._next_status = self._status_window

    def __enter__(self) -> HybridRecorder:
        if self._in_process:
            self._writer = RecordWriter(self.out, self.host.dt_s, bag=self._bag)
        else:
            if self._process is None:
                self._process = WriterProcess(self.out, self.host.dt_s, self._bag)
            # the writer's start-up (imports, the bag's codec) before the run, not in it
            self._process.ready()
        self._thread = threading.Thread(target=self._run, name="hybrid-recorder",
                                        daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        try:
            self.hand_over(final=True)
        finally:
            if self._writer is not None:
                self._writer.close()
            if self._process is not None:
                status = self._process.close()
                if status != 0 and self.error is None:
                    self.error = RecorderError(
                        f"the record's writer process ended with status {status}: "
                        f"{self.csv_path} may be incomplete")

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            try:
                self.hand_over()
            except BaseException as exc:  # noqa: BLE001 - kept; the caller raises it after the run
                self.error = exc
                # a run that cannot be recorded does not go on
                self.host.safety.stop(time.monotonic(), f"the recording failed: {exc}")
                return

    def hand_over(self, final: bool = False) -> None:
        """Hand the writer the samples that can no longer change: all but the newest
        :data:`~ride_sim.hybrid.rig_host.LATE_CYCLES`, which a late feedback may still
        take (:meth:`RigHost.late`), or all of them with ``final`` (the run is over).  The
        recorder's thread calls it every ``period_s``; an offline run may call it after
        each of its cycles instead (``run_offline(after_cycle=...)``, with a ``period_s``
        longer than the run)."""
        host = self.host
        # the newest samples may still take a late feedback (and the last one's twin
        # comes later): they go with a later chunk
        k = host.k if final else host.k - LATE_CYCLES
        lo = self._written
        if k <= lo:
            return
        chunk = Chunk(lo, host.t_ns[lo:k].copy(), host.record[:, lo:k].copy(),
                      float(host.delay_estimate_s[k - 1]), host.phase, host.reason)
        if self._writer is not None:
            self._writer.write(chunk)
        else:
            assert self._process is not None
            self._process.send(chunk)
        self._written = k
        while self._on_status is not None and self._next_status <= k:
            end = self._next_status
            self._on_status(*loop_status(host.record[:, end - self._status_window:end],
                                         float(host.delay_estimate_s[end - 1]), host.phase,
                                         host.reason))
            self._next_status += self._status_window
