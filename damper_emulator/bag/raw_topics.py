"""The raw CDR of some topics of a bag, without rclpy and without per-message rosbags
objects, for the bulk decoders of :mod:`damper_emulator.bag.cdr_fast`.

:func:`read_raw` gives the raw CDR of some topics of a bag, as offsets into one byte
buffer, with their log times (in log-time order, as
:meth:`damper_emulator.bag.Bag.raw_messages` yields them).  Bags with one uncompressed
MCAP file (this project's :class:`~damper_emulator.bag.BagWriter`, closed or killed, and
``ros2 bag record -s mcap`` without compression) are scanned directly (the whole file is
read into memory): a compiled walk over the chunks' records, some tens of ns per record.
Anything else (compressed chunks, several files, other storage) goes through
:func:`~damper_emulator.bag.open_bag`, which also gives the one-line
:class:`~damper_emulator.bag.BagError` for a path that is not a readable bag.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from numpy.typing import NDArray

from damper_emulator.model.jit import plain_kernel

from . import mcap_records as rec
from .cdr_fast import gather_rows
from .messages import BagError

__all__ = ["RawTopic", "read_raw", "warm_up"]

_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


@dataclass(frozen=True)
class RawTopic:
    """The messages of one topic: ``buf[offsets[i] : offsets[i] + lengths[i]]`` is the CDR of
    message ``i``, logged at ``log_ns[i]``; in log-time order."""

    name: str
    msgtype: str
    log_ns: np.ndarray
    offsets: np.ndarray
    lengths: np.ndarray
    buf: np.ndarray

    def __len__(self) -> int:
        return int(self.log_ns.size)

    def data(self, i: int) -> bytes:
        lo = int(self.offsets[i])
        return self.buf[lo:lo + int(self.lengths[i])].tobytes()

    def all_data(self) -> list[bytes]:
        """Every message's bytes, in order."""
        raw = self.buf.base if isinstance(self.buf.base, bytes) else self.buf.tobytes()
        return [raw[o:o + k] for o, k in zip(self.offsets.tolist(), self.lengths.tolist())]


class _Unsupported(Exception):
    """The fast scan does not handle this bag; the rosbags path will."""


@plain_kernel
def _walk_chunks(buf: NDArray[np.uint8], starts: NDArray[np.int64], ends: NDArray[np.int64],
                 opcode: NDArray[np.uint8], content: NDArray[np.int64],
                 length: NDArray[np.int64], channel: NDArray[np.int64],
                 log_ns: NDArray[np.int64]) -> int:  # pragma: no cover - compiled
    """Records inside the chunks' record areas ``[starts[j], ends[j])``: opcode, content
    offset and content length of each, and for a Message record its channel id and log
    time; returns how many, or -1 for a record that overruns its chunk."""
    k = 0
    bound = opcode.size
    for j in range(starts.size):
        pos = starts[j]
        end = ends[j]
        while pos < end:
            if pos + 9 > end or k >= bound:
                return -1
            n = np.int64(0)
            for b in range(8):
                n |= np.int64(buf[pos + 1 + b]) << (8 * b)
            if n < 0 or pos + 9 + n > end:
                return -1
            op = buf[pos]
            opcode[k] = op
            content[k] = pos + 9
            length[k] = n
            if op == 0x05 and n >= 22:
                channel[k] = np.int64(buf[pos + 9]) | (np.int64(buf[pos + 10]) << 8)
                t = np.int64(0)
                for b in range(8):
                    t |= np.int64(buf[pos + 15 + b]) << (8 * b)
                log_ns[k] = t
            else:
                channel[k] = -1
                log_ns[k] = 0
            k += 1
            pos += 9 + n
    return k


def warm_up() -> None:
    """Load the compiled helpers (from numba's on-disk cache, or compile them): a start-up
    cost, paid here rather than in the first read."""
    z = np.zeros(1, dtype=np.int64)
    for buf in (np.zeros(1, dtype=np.uint8), np.frombuffer(b"\0", dtype=np.uint8)):
        # writable and read-only buffers are two specialisations
        _walk_chunks(buf, z[:0], z[:0], np.zeros(1, dtype=np.uint8), z.copy(), z.copy(),
                     z.copy(), z.copy())
        gather_rows(buf, z[:0], np.zeros((0, 1), dtype=np.uint8))


def _u16(buf: np.ndarray, at: np.ndarray) -> np.ndarray:
    value: np.ndarray = buf[at].astype(np.int64) | (buf[at + 1].astype(np.int64) << 8)
    return value


def _u64(buf: np.ndarray, at: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(buf[at[:, None] + np.arange(8)]).view("<u8")[:, 0]


def _string(mv: memoryview, pos: int, end: int) -> tuple[str, int]:
    if pos + 4 > end:
        raise _Unsupported("truncated string")
    n = struct.unpack_from("<I", mv, pos)[0]
    if pos + 4 + n > end:
        raise _Unsupported("truncated string")
    return bytes(mv[pos + 4:pos + 4 + n]).decode(), pos + 4 + n


def _scan_mcap(path: Path, wanted: set[str]
               ) -> tuple[np.ndarray, dict[str, tuple[str, np.ndarray, np.ndarray, np.ndarray]]]:
    """Fast scan of one MCAP file: ``(buf, {topic: (msgtype, log_ns, offsets, lengths)})``.
    Raises _Unsupported for what it does not handle."""
    with open(path, "rb") as fh:
        raw = fh.read()
    buf = np.frombuffer(raw, dtype=np.uint8)
    mv = memoryview(raw)
    size = len(raw)
    magic = rec.MAGIC
    if size < len(magic) or raw[:len(magic)] != magic:
        raise _Unsupported("no MCAP magic")
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int, str]] = {}   # id -> topic, schema id, encoding
    chunk_starts: list[int] = []
    chunk_ends: list[int] = []
    loose: list[tuple[int, int, int]] = []           # top-level records to look at
    pos = len(magic)
    opcode: int | NDArray[np.uint8]   # of one top-level record, then of the chunks' records
    while pos + 9 <= size:
        opcode = raw[pos]
        n = int.from_bytes(raw[pos + 1:pos + 9], "little")
        body = pos + 9
        if body + n > size:
            if opcode >= 0x80:          # a killed bag's reserve (PAD) running past the end
                break
            raise _Unsupported("record overruns the file")
        if opcode == rec.OP_CHUNK:
            if n < 28:
                raise _Unsupported("short chunk")
            compression, p = _string(mv, body + 28, body + n)
            if compression:
                raise _Unsupported(f"{compression} chunk")
            if p + 8 > body + n:
                raise _Unsupported("short chunk")
            records = int.from_bytes(raw[p:p + 8], "little")
            if p + 8 + records > body + n:
                raise _Unsupported("chunk records overrun the chunk")
            chunk_starts.append(p + 8)
            chunk_ends.append(p + 8 + records)
        elif opcode in (rec.OP_SCHEMA, rec.OP_CHANNEL, rec.OP_MESSAGE):
            loose.append((opcode, body, n))
        elif opcode in (rec.OP_DATA_END, rec.OP_FOOTER):
            break
        pos = body + n
    starts = np.array(chunk_starts, dtype=np.int64)
    ends = np.array(chunk_ends, dtype=np.int64)
    bound = int(((ends - starts) // 9).sum()) + 1
    opcode = np.empty(bound, dtype=np.uint8)
    content = np.empty(bound, dtype=np.int64)
    length = np.empty(bound, dtype=np.int64)
    channel = np.empty(bound, dtype=np.int64)
    log_ns = np.empty(bound, dtype=np.int64)
    k = _walk_chunks(buf, starts, ends, opcode, content, length, channel, log_ns)
    if k < 0:
        raise _Unsupported("a record overruns its chunk")
    opcode, content, length = opcode[:k], content[:k], length[:k]
    channel, log_ns = channel[:k], log_ns[:k]
    defs = np.flatnonzero((opcode == rec.OP_SCHEMA) | (opcode == rec.OP_CHANNEL))
    loose += zip(opcode[defs].tolist(), content[defs].tolist(), length[defs].tolist())
    at: int | np.ndarray        # of one record, then of the messages outside chunks
    for op, at, n in loose:
        end = at + n
        if op == rec.OP_SCHEMA:
            if n < 2:
                raise _Unsupported("short schema")
            sid = struct.unpack_from("<H", mv, at)[0]
            schemas[sid], _ = _string(mv, at + 2, end)
        elif op == rec.OP_CHANNEL:
            if n < 4:
                raise _Unsupported("short channel")
            cid, sid = struct.unpack_from("<HH", mv, at)
            topic, p = _string(mv, at + 4, end)
            encoding, _ = _string(mv, p, end)
            channels[cid] = (topic, sid, encoding)
    msg = opcode == rec.OP_MESSAGE
    m_at, m_len, chan, log = content[msg], length[msg], channel[msg], log_ns[msg]
    loose_msgs = np.array([(at, n) for op, at, n in loose if op == rec.OP_MESSAGE],
                          dtype=np.int64).reshape(-1, 2)
    if loose_msgs.size:     # messages outside chunks (allowed by MCAP, rare)
        if (loose_msgs[:, 1] < 22).any():
            raise _Unsupported("short message record")
        at = loose_msgs[:, 0]
        m_at = np.concatenate([m_at, at])
        m_len = np.concatenate([m_len, loose_msgs[:, 1]])
        chan = np.concatenate([chan, _u16(buf, at)])
        log = np.concatenate([log, _u64(buf, at + 6).astype(np.int64)])
    if (m_len < 22).any():
        raise _Unsupported("short message record")
    out: dict[str, tuple[str, np.ndarray, np.ndarray, np.ndarray]] = {}
    for cid, (topic, sid, encoding) in channels.items():
        if topic not in wanted:
            continue
        if encoding != "cdr":
            raise _Unsupported(f"{topic}: {encoding} messages")
        sel = np.flatnonzero(chan == cid)
        order = sel[np.argsort(log[sel], kind="stable")]
        out[topic] = (schemas.get(sid, ""), log[order], m_at[order] + 22, m_len[order] - 22)
    if len(set(chan.tolist()) - set(channels)):
        raise _Unsupported("messages on an undeclared channel")
    return buf, out


def _fast(path: Path, topics: list[str]) -> dict[str, RawTopic]:
    meta_file = path / "metadata.yaml"
    if not path.is_dir() or not meta_file.is_file():
        raise _Unsupported("not a bag directory")
    try:
        meta = yaml.load(meta_file.read_text(), Loader=_LOADER)
        info = meta["rosbag2_bagfile_information"]
        storage = info["storage_identifier"]
        files = list(info["relative_file_paths"])
        declared = {t["topic_metadata"]["name"]: t["topic_metadata"]["type"]
                    for t in info["topics_with_message_count"]}
    except Exception as exc:  # noqa: BLE001 - any oddity: let rosbags judge the bag
        raise _Unsupported(f"metadata: {exc}") from None
    if storage != "mcap" or len(files) != 1:
        raise _Unsupported("not one MCAP file")
    mcap = path / files[0]
    if not mcap.is_file():
        raise _Unsupported("MCAP file missing")
    buf, found = _scan_mcap(mcap, set(topics))
    out = {}
    for topic in topics:
        if topic not in found:
            if topic in declared:       # declared, no channel yet: an empty topic
                out[topic] = RawTopic(topic, declared[topic], *(np.zeros(0, np.int64),) * 3,
                                      buf)
                continue
            raise BagError(f"bag {path}: no topic {topic}")
        msgtype, log, offsets, lengths = found[topic]
        out[topic] = RawTopic(topic, declared.get(topic, msgtype), log, offsets, lengths, buf)
    return out


def _slow(path: Path, topics: list[str]) -> dict[str, RawTopic]:
    from .reader import open_bag

    data: bytes | list[bytes]   # one message's, then one topic's
    with open_bag(path) as bag:
        missing = [t for t in topics if t not in bag.topics]
        if missing:
            raise BagError(f"bag {path}: no topic {', '.join(missing)}")
        rows: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics}
        for topic, log_ns, data in bag.raw_messages(topics):
            rows[topic].append((log_ns, data))
        types = {t: bag.topics[t].msgtype for t in topics}
    out = {}
    for topic in topics:
        data = [d for _, d in rows[topic]]
        lengths = np.array([len(d) for d in data], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
        buf = np.frombuffer(b"".join(data), dtype=np.uint8)
        log = np.array([t for t, _ in rows[topic]], dtype=np.int64)
        out[topic] = RawTopic(topic, types[topic], log, offsets[:lengths.size], lengths, buf)
    return out


def read_raw(path: str | os.PathLike[str], topics: Iterable[str]) -> dict[str, RawTopic]:
    """The raw messages of ``topics`` in the bag at ``path`` (see the module docstring).

    Raises
    ------
    BagError
        One line naming the bag: not a bag, unreadable, a topic it does not have.
    """
    path = Path(path)
    topics = list(topics)
    try:
        return _fast(path, topics)
    except (_Unsupported, OSError, UnicodeDecodeError):
        return _slow(path, topics)
