"""rosbag2 (MCAP storage) writer that survives SIGKILL.

A bag is a directory holding ``metadata.yaml`` (rosbag2 version 9) and one
``<name>_0.mcap`` file (profile ``ros2``, ``cdr`` messages, ``ros2msg``
schemas), as ``ros2 bag record -s mcap`` on Jazzy writes it.

File layout
-----------
While recording the MCAP file is, at every moment::

    magic  Header  block*  PAD  DataEnd  Footer(summary_start=0)  magic

where a *block* is either new Schema + Channel records (:meth:`BagWriter.add_topic`)
or one flush's messages as uncompressed Chunk records, each followed by its
MessageIndex records (optionally ended by a 9-byte empty PAD filler, see
below). PAD is a private record (opcode 0x80; MCAP reserves 0x80..0xFF for
private records and readers skip them by their length) whose content is the
reserved, not yet used part of the file: a sparse hole, created by writing
the DataEnd/Footer/magic tail beyond the end of the file.

Readers that find ``summary_start == 0`` (rosbags, the ``mcap`` package, the
C++ reader's fallback scan) scan the data section, which always parses.

Appending a block ``B`` at the PAD's offset ``P`` is two ``pwrite`` calls:

1. ``B[9:]`` followed by a new PAD header (covering the rest of the reserve)
   at ``P + 9``. These bytes are inside the content of the PAD that still
   starts at ``P``, so readers skip them: the file shows the old state.
2. ``B[:9]`` (the first record's opcode and length) at ``P``: the file shows
   the new state.

A SIGKILL between or during the calls leaves one of the two states. A write
is not atomic against SIGKILL if it crosses a page boundary (the kernel checks
for fatal signals between pages), so every block position ``P`` is kept at
least 9 bytes before a 4 KiB boundary by appending a 9-byte empty PAD filler
to a block when needed (step 2 then never crosses a page), and the 50-byte
DataEnd/Footer/magic tail never crosses one either.

Growing the reserve
-------------------
A block that does not fit grows the reserve to ``max(4 MiB, 2 x block,
min(2 x previous reserve, 64 MiB))`` (64 MiB caps the PAD record that a
reader may load into memory). Two writes, about 10 µs apart:

1. a 9-byte write at ``P`` makes the PAD reach the new DataEnd position,
   beyond the current end of the file;
2. DataEnd/Footer/magic are written there (the file grows, sparse; the old
   tail is now inside the PAD's content).

This is the one step that cannot be atomic in a single file. A SIGKILL
between the two writes leaves a file whose last PAD runs past the end of the
file: rosbags reads it completely (it scans up to the footer and seeks over
the PAD), as ``tests/test_bag.py`` checks, but a strict reader (the ``mcap``
package's stream reader, the C++ fallback scan used by ``ros2 bag play``)
reports a truncated record after the last message. The other order (tail
first) would leave the old magic inside the data section, where rosbags reads
it as a record length of ~2.8e15 and its seek fails. At the demo's ~400 kB/s
a reserve lasts 10 s, 20 s, 40 s, 80 s, then 160 s (64 MiB) each: 7 growths
in the first 10 minutes, then one every ~160 s, so a SIGKILL at a random
moment hits the window with probability of about 10 µs / 160 s = 6e-8.

Closing writes the ``rosbag2`` Metadata record (as a block), then the final
tail ``DataEnd, summary (schemas, channels, chunk indexes, metadata index,
statistics, summary offsets), Footer(summary_start), magic``: its bytes after
the first 9 go in at ``P + 9``, the file is truncated to its real size (from
then on the footer points to the summary, which is how every reader opens a
closed file), and finally the DataEnd header goes in at ``P``.

Flushing and loss bound
-----------------------
:meth:`BagWriter.write` only appends to an in-memory list under a lock. A
daemon thread flushes every ``flush_period_s`` (0.25 s): the pending messages
are sorted by timestamp (stable), written as chunks (at most 1 MiB each), and
``metadata.yaml`` rewritten atomically (temporary file and ``os.replace``).
With ``fsync``, a second daemon thread then ``fdatasync``-s both files: a disk
slow to sync (a busy machine's, for seconds) delays only the protection against a
power loss, never the writes that a SIGKILL would otherwise lose.
:meth:`BagWriter.flush` and :meth:`BagWriter.close` sync before they return. The
background flush holds back the
messages stamped within 50 ms of the newest one until its next round, so a
message that another thread stamped earlier but handed over a little later
still goes in in timestamp order. A SIGKILL loses what was not yet written: at
most one period + 50 ms + one flush's duration (about 0.3 s).

Timestamp order: rosbags reads an unclosed (or killed) file by a linear scan
and refuses one whose log times go backwards *across* chunks. Within a flush
the writer sorts, and the hold-back absorbs hand-over delays up to 50 ms; a
message stamped earlier than that (a clock stepped back, a topic stamped on
another clock) breaks it, and the writer logs a warning the first time. A
closed bag has chunk indexes and any order reads fine.
"""

from __future__ import annotations

import bisect
import logging
import math
import os
import struct
import threading
import zlib
from collections.abc import Callable, Mapping
from operator import itemgetter
from pathlib import Path
from types import TracebackType

from rosbags.rosbag2.metadata import dump_qos_v9

from . import mcap_records as rec
from .messages import BagError, msgdef, type_hash
from .qos import Qos, Topic, dump_yaml, qos_yaml

__all__ = ["BagWriter"]

_INITIAL_RESERVE = 4 * 2**20
_MAX_RESERVE = 64 * 2**20
_CHUNK_LIMIT = 2**20
_PAGE = 4096
_LIBRARY = "damper-hil"
_ROS_DISTRO = "jazzy"
_NO_START = 2**63 - 1  # rosbag2's starting_time of an empty bag
_TAIL_SIZE = rec.DATA_END_SIZE + rec.FOOTER_SIZE + len(rec.MAGIC)
_U64_LIMIT = 2**64
_REORDER_NS = 50_000_000  # the background flush holds back the newest 50 ms
_TIMESTAMP = itemgetter(0)

_log = logging.getLogger(__name__)




def _tail_position(offset: int) -> int:
    """``offset`` or the next page start, so that the 50-byte tail write stays inside one page."""
    if offset % _PAGE > _PAGE - _TAIL_SIZE:
        offset += _PAGE - offset % _PAGE
    return offset


class BagWriter:
    """Write a rosbag2 bag with MCAP storage that stays readable if the process is killed.

    Parameters
    ----------
    path : str or Path
        Bag directory to create. It may exist if it is empty.
    flush_period_s : float, optional
        Period of the background flush (0.25 s: a SIGKILL loses at most ~0.5 s).
    custom_data : mapping of str to str, optional
        rosbag2 ``custom_data``.
    fsync : bool, optional
        ``fdatasync`` the MCAP file and ``metadata.yaml`` after each flush
        (protects against a power loss too). The background flush leaves it to a
        thread of its own, so that a slow sync never holds back the writes;
        :meth:`flush` and :meth:`close` sync before they return.
    flush_thread_setup : callable, optional
        Called first on the background flush thread (e.g. to give it the
        real-time priority of the thread that calls :meth:`write`: the two share
        Python's GIL).

    Raises
    ------
    BagError
        The directory exists and is not empty, or cannot be created.

    Notes
    -----
    Thread safe. :meth:`write` costs about a microsecond and never does I/O;
    :meth:`add_topic`, :meth:`flush` and :meth:`close` do. :meth:`flush` writes
    everything queued, without the background flush's 50 ms hold-back. Always
    :meth:`close` (or use ``with``): an unclosed writer's thread keeps flushing
    until the process ends, and the file stays an unclosed (scan-only) bag.
    See the module docstring for the file layout and the crash-safety argument.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        flush_period_s: float = 0.25,
        custom_data: Mapping[str, str] | None = None,
        fsync: bool = True,
        flush_thread_setup: Callable[[], object] | None = None,
    ) -> None:
        self.path = Path(path)
        if (
            isinstance(flush_period_s, bool)
            or not isinstance(flush_period_s, (int, float))
            or not (math.isfinite(flush_period_s) and flush_period_s > 0)
        ):
            raise BagError(f"bag {self.path}: flush_period_s must be a positive number of seconds")
        custom = dict(custom_data or {})
        for key, value in custom.items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise BagError(
                    f"bag {self.path}: custom_data must map str to str, got {key!r}: {value!r}"
                )
        self._custom_data = custom
        self._flush_period = float(flush_period_s)
        self._fsync = bool(fsync)

        try:
            if self.path.exists():
                if not self.path.is_dir():
                    raise BagError(f"bag {self.path}: exists and is not a directory")
                if any(self.path.iterdir()):
                    raise BagError(
                        f"bag {self.path}: directory exists and is not empty, not overwriting"
                    )
            else:
                self.path.mkdir(parents=True)
        except OSError as exc:
            raise BagError(
                f"bag {self.path}: cannot create the directory: {exc.strerror or exc}"
            ) from None

        self.mcap_name = f"{self.path.name}_0.mcap"
        self._lock = threading.Lock()  # pending messages, topic registry, closed flag
        self._io_lock = threading.Lock()  # the file and the flushed-state bookkeeping
        self._pending: list[tuple[int, int, bytes]] = []
        self._held: list[
            tuple[int, int, bytes]
        ] = []  # under _io_lock: the background flush's hold-back
        self._warned_order = False
        self._pending_defs: list[bytes] = []
        self._channel_of: dict[Topic, int] = {}
        self._topics: list[Topic] = []
        self._schema_ids: dict[str, int] = {}
        self._schema_records: list[bytes] = []
        self._channel_records: list[bytes] = []
        self._closed = False
        self._error: str | None = None

        # flushed state (under _io_lock)
        self._counts: dict[int, int] = {}
        self._seq: dict[int, int] = {}
        self._chunk_indexes: list[bytes] = []
        self._message_count = 0
        self._start = _NO_START
        self._end = 0

        try:
            self._fd = os.open(
                self.path / self.mcap_name, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644
            )
        except OSError as exc:
            raise BagError(
                f"bag {self.path}: cannot create {self.mcap_name}: {exc.strerror or exc}"
            ) from None
        try:
            head = rec.MAGIC + rec.header("ros2", _LIBRARY)
            self._pos = len(head)
            self._reserve = _INITIAL_RESERVE
            self._reserve_end = _tail_position(self._pos + self._reserve)
            self._pwrite(head + rec.pad(self._reserve_end - self._pos - rec.RECORD_HEADER_SIZE), 0)
            self._write_tail(self._reserve_end)
            self._write_metadata_yaml()
        except OSError as exc:
            os.close(self._fd)
            raise BagError(f"bag {self.path}: cannot write: {exc.strerror or exc}") from None

        self._stop = threading.Event()
        #: set by each background flush: the sync thread has new writes to make durable
        #: (before the flush thread starts: its first flush sets it)
        self._sync_wanted = threading.Event()
        self._sync_thread: threading.Thread | None = None
        if self._fsync:
            self._sync_thread = threading.Thread(
                target=self._sync_run, name=f"bag-sync {self.path.name}", daemon=True
            )
            self._sync_thread.start()
        self._thread_setup = flush_thread_setup
        self._thread = threading.Thread(
            target=self._run, name=f"bag-flush {self.path.name}", daemon=True
        )
        self._thread.start()

    # ------------------------------------------------------------------ API

    def add_topic(self, name: str, msgtype: str, *, qos: Qos | None = None) -> Topic:
        """Register a topic; allowed at any time, also after messages were written.

        Parameters
        ----------
        name : str
            Topic name, starting with ``/``.
        msgtype : str
            ROS 2 type, e.g. ``"sensor_msgs/msg/JointState"`` (must be in the Jazzy typestore).
        qos : Qos, optional
            Offered QoS (default: reliable, volatile, keep_last 10).

        Returns
        -------
        Topic
            Handle for :meth:`write`.

        Raises
        ------
        BagError
            Bad or duplicate name, unknown type, closed writer.

        Notes
        -----
        Writes the new Schema/Channel records and ``metadata.yaml`` at once
        (a flush), so it is not meant for a real-time path.
        """
        if not isinstance(name, str) or not name.startswith("/") or len(name) < 2:
            raise BagError(
                f"bag {self.path}: topic name must be a string starting with '/', got {name!r}"
            )
        if qos is None:
            qos = Qos()
        elif not isinstance(qos, Qos):
            raise BagError(f"bag {self.path}: qos must be a Qos, got {type(qos).__name__}")
        try:
            definition = msgdef(msgtype)
            rihs01 = type_hash(msgtype)
        except BagError as exc:
            raise BagError(f"bag {self.path}: topic {name}: {exc}") from None
        metadata = {"offered_qos_profiles": qos_yaml(qos), "topic_type_hash": rihs01}
        with self._io_lock:
            with self._lock:
                self._check_open()
                if any(t.name == name for t in self._topics):
                    raise BagError(f"bag {self.path}: topic {name} was already added")
                if len(self._topics) >= 0xFFFF:
                    raise BagError(f"bag {self.path}: too many topics")
                schema_id = self._schema_ids.get(msgtype)
                if schema_id is None:
                    schema_id = len(self._schema_ids) + 1
                    self._schema_ids[msgtype] = schema_id
                    schema = rec.schema(schema_id, msgtype, "ros2msg", definition.encode())
                    self._schema_records.append(schema)
                    self._pending_defs.append(schema)
                channel_id = len(self._topics) + 1
                channel = rec.channel(channel_id, schema_id, name, "cdr", metadata)
                self._channel_records.append(channel)
                self._pending_defs.append(channel)
                topic = Topic(name, msgtype, qos, channel_id)
                self._topics.append(topic)
                self._channel_of[topic] = channel_id
                self._counts[channel_id] = 0
                self._seq[channel_id] = 0
            self._flush_locked()
        return topic

    def write(self, topic: Topic, timestamp_ns: int, data: bytes) -> None:
        """Queue one serialized message; the flush thread writes it within ``flush_period_s``.

        Parameters
        ----------
        topic : Topic
            Handle from :meth:`add_topic`.
        timestamp_ns : int
            Receive time in ns since the epoch (MCAP log and publish time).
        data : bytes
            CDR bytes (``bytearray``/``memoryview`` are copied).

        Raises
        ------
        BagError
            Closed or failed writer, unknown topic handle, non-bytes data, a
            timestamp that is not an integer in [0, 2**64).
        """
        if type(data) is not bytes:
            if isinstance(data, (bytearray, memoryview)):
                data = bytes(data)
            else:
                raise BagError(
                    f"bag {self.path}: message data must be bytes (serialized CDR), "
                    f"got {type(data).__name__}"
                )
        if type(timestamp_ns) is not int:
            timestamp_ns = self._as_int_timestamp(timestamp_ns)
        if not 0 <= timestamp_ns < _U64_LIMIT:
            raise BagError(
                f"bag {self.path}: timestamp_ns must be in [0, 2**64), got {timestamp_ns}"
            )
        with self._lock:
            if self._closed or self._error is not None:
                self._check_open()
            try:
                channel_id = self._channel_of[topic]
            except (KeyError, TypeError):
                raise BagError(f"bag {self.path}: unknown topic handle {topic!r}") from None
            self._pending.append((timestamp_ns, channel_id, data))

    def flush(self) -> None:
        """Write all queued messages now (the background thread does this periodically).

        Raises
        ------
        BagError
            Closed writer, or the write failed.
        """
        with self._io_lock:
            with self._lock:
                self._check_open()
            self._flush_locked(durable=True)

    def close(self) -> None:
        """Flush and write the final summary, truncate the file, write the final metadata.yaml.

        Closing twice is a no-op.

        Raises
        ------
        BagError
            If writing fails (the file is then left in its last valid state).
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join()
        if self._sync_thread is not None:
            self._sync_wanted.set()  # wakes it to see _stop; it touches the file no more
            self._sync_thread.join()
        with self._io_lock:
            try:
                if self._error is None:
                    self._flush_locked()
                    self._finish()
            finally:
                os.close(self._fd)
        if self._error is not None:
            raise BagError(f"bag {self.path}: {self._error}")

    @property
    def closed(self) -> bool:
        """Whether :meth:`close` was called."""
        return self._closed

    @property
    def topics(self) -> tuple[Topic, ...]:
        """The topics added so far."""
        with self._lock:
            return tuple(self._topics)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"BagWriter({str(self.path)!r}, {len(self._topics)} topics, {state})"

    # ------------------------------------------------------------ internals

    def _check_open(self) -> None:
        """Raise if closed or failed (caller holds ``_lock``)."""
        if self._error is not None:
            raise BagError(f"bag {self.path}: writer failed earlier: {self._error}")
        if self._closed:
            raise BagError(f"bag {self.path}: writer is closed")

    def _as_int_timestamp(self, value: object) -> int:
        if isinstance(value, bool):
            raise BagError(f"bag {self.path}: timestamp_ns must be an integer, got bool")
        try:
            return int(value.__index__())  # type: ignore[attr-defined]
        except (AttributeError, TypeError):
            raise BagError(
                f"bag {self.path}: timestamp_ns must be an integer, got {type(value).__name__}"
            ) from None

    def _run(self) -> None:
        if self._thread_setup is not None:
            self._thread_setup()
        while not self._stop.wait(self._flush_period):
            with self._io_lock:
                if self._closed or self._error is not None:
                    return
                try:
                    self._flush_locked(hold_back=True)
                except BagError:
                    return

    def _sync_run(self) -> None:
        """The sync thread: ``fdatasync`` what the background flushes wrote, as often as
        the disk allows (outside ``_io_lock``: the flushes go on meanwhile)."""
        while True:
            self._sync_wanted.wait()
            self._sync_wanted.clear()
            if self._stop.is_set():
                return
            try:
                self._sync_files()
            except OSError as exc:
                with self._lock:
                    if self._error is None:
                        self._error = f"syncing failed: {exc.strerror or exc}"
                return

    def _sync_files(self) -> None:
        """``fdatasync`` the MCAP file and the current ``metadata.yaml``."""
        os.fdatasync(self._fd)
        fd = os.open(self.path / "metadata.yaml", os.O_RDONLY | os.O_CLOEXEC)
        try:
            os.fdatasync(fd)
        finally:
            os.close(fd)

    def _pwrite(self, data: bytes, offset: int) -> None:
        view = memoryview(data)
        while view:
            n = os.pwrite(self._fd, view, offset)
            view = view[n:]
            offset += n

    def _write_tail(self, at: int) -> None:
        self._pwrite(rec.data_end() + rec.footer(0, 0, 0) + rec.MAGIC, at)

    def _append(self, block: bytes) -> None:
        """Append ``block`` (whole records) at the PAD's offset; valid file at every step."""
        start = self._pos
        end = start + len(block)
        if end % _PAGE > _PAGE - rec.RECORD_HEADER_SIZE:
            block += rec.pad(0)  # keep the next 9-byte header write inside one page
            end += rec.RECORD_HEADER_SIZE
        if end + rec.RECORD_HEADER_SIZE > self._reserve_end:
            self._grow(end + rec.RECORD_HEADER_SIZE - start)
        rest = self._reserve_end - end - rec.RECORD_HEADER_SIZE
        self._pwrite(
            block[rec.RECORD_HEADER_SIZE :] + rec.pad(rest), start + rec.RECORD_HEADER_SIZE
        )
        self._pwrite(block[: rec.RECORD_HEADER_SIZE], start)
        self._pos = end

    def _grow(self, needed: int) -> None:
        """Move the tail out so that ``needed`` bytes fit at the PAD's offset."""
        self._reserve = max(_INITIAL_RESERVE, 2 * needed, min(2 * self._reserve, _MAX_RESERVE))
        new_end = _tail_position(self._pos + self._reserve)
        assert new_end >= self._reserve_end + _TAIL_SIZE  # the old tail stays intact until covered
        self._grow_pad(new_end)
        self._grow_tail(new_end)

    def _grow_pad(self, new_end: int) -> None:
        # Window opens: the PAD at _pos now reaches beyond the end of the file.
        self._pwrite(rec.pad(new_end - self._pos - rec.RECORD_HEADER_SIZE), self._pos)

    def _grow_tail(self, new_end: int) -> None:
        # Window closes: the file ends in the new tail, the old one is inside the PAD.
        self._write_tail(new_end)
        self._reserve_end = new_end

    def _build_chunks(
        self, pending: list[tuple[int, int, bytes]], base: int
    ) -> tuple[bytes, list[bytes]]:
        """Chunk + MessageIndex records for ``pending`` (sorted) placed at file offset ``base``."""
        pack = rec.MESSAGE_PREFIX.pack
        seq = self._seq
        parts: list[bytes] = []
        indexes: list[bytes] = []
        offset = base
        i, n = 0, len(pending)
        while i < n:
            records: list[bytes] = []
            index: dict[int, list[tuple[int, int]]] = {}
            size = 0
            start_time = pending[i][0]
            t = start_time
            while i < n and size < _CHUNK_LIMIT:
                t, channel_id, data = pending[i]
                s = seq[channel_id] = (seq[channel_id] + 1) & 0xFFFFFFFF
                entries = index.get(channel_id)
                if entries is None:
                    entries = index[channel_id] = []
                entries.append((t, size))
                records.append(pack(rec.OP_MESSAGE, 22 + len(data), channel_id, s, t, t))
                records.append(data)
                size += 31 + len(data)
                i += 1
            body = b"".join(records)
            chunk = rec.chunk(start_time, t, body, zlib.crc32(body))
            chunk_start = offset
            parts.append(chunk)
            offset += len(chunk)
            index_start = offset
            index_offsets: list[tuple[int, int]] = []
            for channel_id in sorted(index):
                index_offsets.append((channel_id, offset))
                mi = rec.message_index(channel_id, index[channel_id])
                parts.append(mi)
                offset += len(mi)
            indexes.append(
                rec.chunk_index(
                    start_time,
                    t,
                    chunk_start,
                    len(chunk),
                    index_offsets,
                    offset - index_start,
                    len(body),
                )
            )
        return b"".join(parts), indexes

    def _flush_locked(self, hold_back: bool = False, durable: bool = False) -> None:
        """Write queued definitions and messages (caller holds ``_io_lock``).

        With ``hold_back`` (the background flush), messages stamped within
        ``_REORDER_NS`` of the newest one wait for the next flush, so that a
        message handed over slightly late by another thread still lands in
        timestamp order; what waited is always written by the next flush.
        With ``fsync``, ``durable`` syncs the files before returning; otherwise the
        sync thread does.
        """
        if self._error is not None:
            raise BagError(f"bag {self.path}: writer failed earlier: {self._error}")
        with self._lock:
            pending, self._pending = self._pending, []
            defs, self._pending_defs = self._pending_defs, []
        held, self._held = self._held, []
        pending.sort(key=_TIMESTAMP)
        if hold_back and pending:
            cutoff = pending[-1][0] - _REORDER_NS
            if held:
                cutoff = max(cutoff, held[-1][0])
            split = bisect.bisect_right(pending, cutoff, key=_TIMESTAMP)
            pending, self._held = pending[:split], pending[split:]
        if held:
            pending = sorted(held + pending, key=_TIMESTAMP)
        if not pending and not defs:
            return
        try:
            head = b"".join(defs)
            chunks, indexes = (
                self._build_chunks(pending, self._pos + len(head)) if pending else (b"", [])
            )
            self._append(head + chunks)
            self._chunk_indexes.extend(indexes)
            counts = self._counts
            for _, channel_id, _ in pending:
                counts[channel_id] += 1
            if pending:
                if pending[0][0] < self._end and not self._warned_order:
                    self._warned_order = True
                    _log.warning(
                        "bag %s: a message stamped %d ns arrived after one stamped %d ns was "
                        "written; "
                        "until it is closed, rosbags cannot read this bag (closed, it reads fine)",
                        self.path,
                        pending[0][0],
                        self._end,
                    )
                self._message_count += len(pending)
                self._start = min(self._start, pending[0][0])
                self._end = max(self._end, pending[-1][0])
            self._write_metadata_yaml()
            if self._fsync:
                if durable:
                    self._sync_files()
                else:
                    self._sync_wanted.set()
        except OSError as exc:
            self._error = f"writing failed: {exc.strerror or exc}"
            raise BagError(f"bag {self.path}: {self._error}") from None

    def _finish(self) -> None:
        """Replace PAD/DataEnd/Footer by the final summary and truncate (under ``_io_lock``)."""
        try:
            meta = rec.metadata(
                "rosbag2",
                {
                    "serialized_metadata": dump_yaml(
                        self._metadata()["rosbag2_bagfile_information"]
                    )
                },
            )
            metadata_offset = self._pos
            self._append(meta)

            summary_start = self._pos + rec.DATA_END_SIZE
            groups: list[tuple[int, bytes]] = [
                (rec.OP_SCHEMA, b"".join(self._schema_records)),
                (rec.OP_CHANNEL, b"".join(self._channel_records)),
                (rec.OP_CHUNK_INDEX, b"".join(self._chunk_indexes)),
                (rec.OP_METADATA_INDEX, rec.metadata_index(metadata_offset, len(meta), "rosbag2")),
                (
                    rec.OP_STATISTICS,
                    rec.statistics(
                        self._message_count,
                        len(self._schema_records),
                        len(self._channel_records),
                        1,
                        len(self._chunk_indexes),
                        self._start if self._message_count else 0,
                        self._end,
                        self._counts,
                    ),
                ),
            ]
            summary = bytearray()
            offsets = bytearray()
            for opcode, data in groups:
                if data:
                    offsets += rec.summary_offset(opcode, summary_start + len(summary), len(data))
                    summary += data
            summary_offset_start = summary_start + len(summary)
            summary += offsets
            footer_head = rec.record_header(rec.OP_FOOTER, 20) + struct.pack(
                "<QQ", summary_start, summary_offset_start
            )
            crc = zlib.crc32(bytes(summary) + footer_head)
            footer = rec.footer(summary_start, summary_offset_start, crc)
            tail = rec.data_end() + bytes(summary) + footer + rec.MAGIC
            if self._pos + len(tail) > self._reserve_end:
                self._grow(len(tail) + rec.RECORD_HEADER_SIZE)
            self._pwrite(tail[rec.RECORD_HEADER_SIZE :], self._pos + rec.RECORD_HEADER_SIZE)
            os.ftruncate(self._fd, self._pos + len(tail))
            self._pwrite(tail[: rec.RECORD_HEADER_SIZE], self._pos)
            self._pos += len(tail)
            self._write_metadata_yaml()
            if self._fsync:
                self._sync_files()
        except OSError as exc:
            self._error = f"closing failed: {exc.strerror or exc}"

    def _metadata(self) -> dict[str, dict[str, object]]:
        count = self._message_count
        start = self._start if count else _NO_START
        duration = self._end - self._start if count else 0
        topics = [
            {
                "topic_metadata": {
                    "name": t.name,
                    "type": t.msgtype,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": dump_qos_v9([t.qos.to_rosbags()]),
                    "type_description_hash": type_hash(t.msgtype),
                },
                "message_count": self._counts[t.channel_id],
            }
            for t in self._topics
        ]
        return {
            "rosbag2_bagfile_information": {
                "version": 9,
                "storage_identifier": "mcap",
                "duration": {"nanoseconds": duration},
                "starting_time": {"nanoseconds_since_epoch": start},
                "message_count": count,
                "topics_with_message_count": topics,
                "compression_format": "",
                "compression_mode": "",
                "relative_file_paths": [self.mcap_name],
                "files": [
                    {
                        "path": self.mcap_name,
                        "starting_time": {"nanoseconds_since_epoch": start},
                        "duration": {"nanoseconds": duration},
                        "message_count": count,
                    }
                ],
                "custom_data": dict(self._custom_data) or None,
                "ros_distro": _ROS_DISTRO,
            }
        }

    def _write_metadata_yaml(self) -> None:
        """Replace metadata.yaml atomically (temporary file + rename); syncing it is
        :meth:`_sync_files`' (ext4 writes a file renamed over another out with the rename)."""
        text = dump_yaml(self._metadata()).encode()
        tmp = self.path / ".metadata.yaml.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
        try:
            view = memoryview(text)
            while view:
                view = view[os.write(fd, view) :]
        finally:
            os.close(fd)
        os.replace(tmp, self.path / "metadata.yaml")
