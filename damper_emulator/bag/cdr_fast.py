"""Fast columnar access to ``sensor_msgs/msg/JointState`` topics of a bag, without rclpy and
without per-message rosbags objects.

Three parts, used by the offline replay (:mod:`damper_emulator.replay`):

:func:`read_raw`
    The raw CDR of some topics of a bag, as offsets into one byte buffer, with their log
    times (in log-time order, as :meth:`damper_emulator.bag.Bag.raw_messages` yields them).
    Bags with one uncompressed MCAP file (this project's :class:`~damper_emulator.bag.BagWriter`,
    closed or killed, and ``ros2 bag record -s mcap`` without compression) are scanned
    directly (the whole file is read into memory): a compiled walk over the chunks'
    records, some tens of ns per record.  Anything else (compressed chunks, several files,
    other storage) goes through
    :func:`~damper_emulator.bag.open_bag`, which also gives the one-line
    :class:`~damper_emulator.bag.BagError` for a path that is not a readable bag.
:func:`decode_joint_states`
    JointState CDR → arrays.  Messages are grouped by length; within a group every message
    whose *structural* bytes (encapsulation kind, ``frame_id``, ``name``, sequence lengths;
    not the stamps, the float64 values, the alignment padding or trailing bytes) equal
    those of the group's first message has the same layout, so its stamp and values are
    read for the whole group at once with numpy views.  Other messages (rare: a bag whose
    names or sequence lengths change) are decoded one at a time by :func:`decode_joint_state`.
:func:`encode_joint_states`
    Arrays → JointState CDR for many messages of one layout: a template filled in with
    numpy.  The bytes equal :func:`damper_emulator.bag.messages.joint_state` (rosbags)
    for the same values (``tests/test_replay.py`` checks it).

CDR layout of a JointState (XCDR1 little endian, offsets relative to the body after the
4-byte encapsulation header): ``int32 sec, uint32 nanosec``; ``frame_id`` (uint32 length
including the NUL, bytes, NUL); ``name`` (uint32 count, then each string aligned to 4);
``position``, ``velocity``, ``effort`` (uint32 count aligned to 4; when not empty the
float64 values aligned to 8).  Trailing bytes after the message are ignored, as rclpy does
(see :mod:`damper_emulator.bag.messages`).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from damper_emulator.model.jit import plain_kernel

from . import mcap_records as rec
from .messages import BagError

__all__ = [
    "JointStateCodec",
    "JointStateDecoder",
    "JointStateSample",
    "JointStates",
    "RawTopic",
    "decode_joint_state",
    "decode_joint_states",
    "encode_joint_state",
    "encode_joint_states",
    "read_raw",
    "rows_to_bytes",
    "warm_up",
]

JOINT_STATE = "sensor_msgs/msg/JointState"
_FIELDS = ("position", "velocity", "effort")
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


# ------------------------------------------------------------------------------------------
# one message, pure Python


@dataclass(frozen=True)
class _Layout:
    """Where the fields of one JointState CDR lie (absolute offsets, little endian only)."""

    size: int                                   # bytes used (without trailing bytes)
    frame_id: str
    names: tuple[str, ...]
    sequences: tuple[tuple[int, int], ...]      # (offset of the first float64, count) × 3
    structural: tuple[tuple[int, int], ...]     # [start, end) byte ranges that fix the layout


def _parse(data: bytes | memoryview) -> tuple[int, _Layout, tuple[np.ndarray, ...], bool]:
    """``(stamp_ns, layout, (position, velocity, effort), little_endian)`` of one JointState.

    Raises BagError (one line) for data that is not a complete JointState CDR.
    """
    mv = memoryview(data)
    n = len(mv)
    if n < 4 or mv[0] != 0 or mv[1] not in (0, 1):
        raise BagError(f"cannot decode {JOINT_STATE}: not CDR (encapsulation "
                       f"{bytes(mv[:4]).hex() or 'missing'})")
    little = mv[1] == 1
    e = "<" if little else ">"
    u32 = struct.Struct(e + "I")
    base = 4
    pos = 0                                     # relative to the body
    structural = [(0, 2)]

    def need(count: int) -> None:
        if base + pos + count > n:
            raise BagError(f"cannot decode {JOINT_STATE}: truncated at byte {base + pos} "
                           f"of {n}")

    def align(k: int) -> None:
        nonlocal pos
        pos += -pos % k

    def uint32() -> int:
        nonlocal pos
        align(4)
        need(4)
        value: int = u32.unpack_from(mv, base + pos)[0]
        structural.append((base + pos, base + pos + 4))
        pos += 4
        return value

    def string() -> str:
        nonlocal pos
        length = uint32()
        if length == 0:
            raise BagError(f"cannot decode {JOINT_STATE}: string without its NUL")
        need(length)
        raw = bytes(mv[base + pos: base + pos + length])
        structural.append((base + pos, base + pos + length))
        pos += length
        if raw[-1] != 0:
            raise BagError(f"cannot decode {JOINT_STATE}: string not NUL-terminated")
        try:
            return raw[:-1].decode()
        except UnicodeDecodeError:
            raise BagError(f"cannot decode {JOINT_STATE}: string not UTF-8") from None

    need(8)
    sec, nanosec = struct.unpack_from(e + "iI", mv, base)
    pos = 8
    frame_id = string()
    count = uint32()
    if count > n:
        raise BagError(f"cannot decode {JOINT_STATE}: {count} names in {n} bytes")
    names = tuple(string() for _ in range(count))
    sequences = []
    values = []
    for _ in _FIELDS:
        count = uint32()
        if count:
            align(8)
            need(8 * count)
            sequences.append((base + pos, count))
            values.append(np.frombuffer(mv, dtype=e + "f8", count=count,
                                        offset=base + pos).astype(float))
            pos += 8 * count
        else:
            sequences.append((base + pos, 0))
            values.append(np.empty(0))
    layout = _Layout(base + pos, frame_id, names, tuple(sequences), tuple(structural))
    return sec * 1_000_000_000 + nanosec, layout, tuple(values), little


def decode_joint_state(data: bytes | memoryview) -> tuple[int, str, tuple[str, ...],
                                                          np.ndarray, np.ndarray, np.ndarray]:
    """One JointState CDR (either endianness) → ``(stamp_ns, frame_id, names, position,
    velocity, effort)``; trailing bytes are ignored.

    Raises
    ------
    BagError
        Not a complete JointState CDR (one line).
    """
    stamp, layout, (p, v, f), _ = _parse(data)
    return stamp, layout.frame_id, layout.names, p, v, f


def _cdr_string(text: str, pos: int) -> tuple[bytes, int]:
    raw = text.encode() + b"\0"
    pad = b"\0" * (-pos % 4)
    return pad + struct.pack("<I", len(raw)) + raw, pos + len(pad) + 4 + len(raw)


def encode_joint_state(stamp_ns: int, names: Sequence[str], position: ArrayLike,
                       velocity: ArrayLike, effort: ArrayLike, frame_id: str = "") -> bytes:
    """One JointState as little-endian CDR (the bytes of
    :func:`damper_emulator.bag.messages.joint_state`, without rosbags)."""
    sec, nanosec = _split_stamp(np.asarray([stamp_ns], dtype=np.int64))
    out = [b"\x00\x01\x00\x00", struct.pack("<iI", int(sec[0]), int(nanosec[0]))]
    pos = 8
    part, pos = _cdr_string(frame_id, pos)
    out.append(part)
    pad = b"\0" * (-pos % 4)
    out.append(pad + struct.pack("<I", len(names)))
    pos += len(pad) + 4
    for name in names:
        part, pos = _cdr_string(str(name), pos)
        out.append(part)
    for values in (position, velocity, effort):
        arr = np.ascontiguousarray(values, dtype="<f8")
        if arr.ndim != 1:
            raise ValueError(f"JointState values must be one-dimensional, got {arr.shape}")
        pad = b"\0" * (-pos % 4)
        out.append(pad + struct.pack("<I", arr.size))
        pos += len(pad) + 4
        if arr.size:
            pad = b"\0" * (-pos % 8)
            out.append(pad + arr.tobytes())
            pos += len(pad) + 8 * arr.size
    return b"".join(out)


def _split_stamp(stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    sec, nanosec = np.divmod(stamp_ns, 1_000_000_000)
    bad = (sec < 0) | (sec >= 2**31)
    if bad.any():
        raise ValueError(f"stamp_ns {int(stamp_ns[np.argmax(bad)])} out of range for "
                         f"builtin_interfaces/Time")
    return sec, nanosec


# ------------------------------------------------------------------------------------------
# one message of a known layout, precompiled (the live nodes' 1 kHz topics)


class JointStateSample(NamedTuple):
    """One decoded JointState; the values as tuples of float."""

    stamp_ns: int
    frame_id: str
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]


class JointStateCodec:
    """Encode and decode JointState CDR of one layout (``frame_id``, ``name`` and the three
    sequence lengths) with one precompiled :class:`struct.Struct`.

    A fraction of the cost of an rclpy message object (benchmarks/message_bench.py), which
    at the 1 kHz of the control topics is several per cent of a core per topic and node.
    The bytes equal :func:`encode_joint_state`'s for the same values (alignment padding
    written as zeros); decoding compares the structural bytes (not the padding, which
    rmw_fastrtps leaves uninitialised) and ignores trailing bytes.

    Parameters
    ----------
    names : sequence of str
    counts : (int, int, int)
        Lengths of ``position``, ``velocity`` and ``effort``.
    frame_id : str
    """

    def __init__(self, names: Sequence[str], counts: tuple[int, int, int],
                 frame_id: str = ""):
        template = encode_joint_state(0, names, np.zeros(counts[0]), np.zeros(counts[1]),
                                      np.zeros(counts[2]), frame_id=frame_id)
        _, layout, _, _ = _parse(template)
        self.names = layout.names
        self.frame_id = layout.frame_id
        self.counts = counts
        self.size = layout.size
        # the message as fields: the stamp, the values, the structural bytes (constants,
        # compared on decoding) and pad bytes (skipped on decoding, zero on encoding)
        spans = sorted([(a, b, "s") for a, b in layout.structural]
                       + [(4, 12, "stamp")]
                       + [(off, off + 8 * n, "d") for off, n in layout.sequences if n])
        fmt, constants, at = ["<"], [], 0
        for a, b, kind in spans:
            if a > at:
                fmt.append(f"{a - at}x")
            if kind == "s":
                fmt.append(f"{b - a}s")
                constants.append(template[a:b])
            elif kind == "stamp":
                fmt.append("iI")
            else:
                fmt.append(f"{(b - a) // 8}d")
            at = b
        if self.size > at:
            fmt.append(f"{self.size - at}x")
        self._struct = struct.Struct("".join(fmt))
        self._constants = tuple(constants)
        head = sum(1 for a, _, k in spans if k == "s" and a < 4)
        self._head = self._constants[:head]
        self._tail_plan = self._plan(spans, head)
        n_values = sum(counts)
        self._value_slices = self._slices(counts)
        self._n_values = n_values

    @staticmethod
    def _plan(spans: list[tuple[int, int, str]], head: int) -> list[tuple[str, int]]:
        """After the stamp: ``("c", i)`` constant ``i`` or ``("v", n)`` n values."""
        plan, k = [], head
        for a, b, kind in spans:
            if a < 12:
                continue
            if kind == "s":
                plan.append(("c", k))
                k += 1
            else:
                plan.append(("v", (b - a) // 8))
        return plan

    @staticmethod
    def _slices(counts: tuple[int, int, int]) -> tuple[slice, slice, slice]:
        a = counts[0]
        b = a + counts[1]
        return slice(0, a), slice(a, b), slice(b, b + counts[2])

    def encode(self, stamp_ns: int, values: Sequence[float]) -> bytes:
        """The CDR of a message stamped ``stamp_ns`` whose ``position``, ``velocity`` and
        ``effort`` are ``values`` one after the other (``sum(counts)`` floats)."""
        if len(values) != self._n_values:
            raise ValueError(f"{self._n_values} values expected, got {len(values)}")
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        if not 0 <= sec < 2**31:
            raise ValueError(f"stamp_ns {stamp_ns} out of range for builtin_interfaces/Time")
        args: list[object] = [*self._head, sec, nanosec]
        i = 0
        for kind, k in self._tail_plan:
            if kind == "c":
                args.append(self._constants[k])
            else:
                args.extend(values[i:i + k])
                i += k
        return self._struct.pack(*args)

    def decode(self, data: bytes | memoryview) -> JointStateSample | None:
        """The message in ``data`` if it has this layout (trailing bytes ignored), else
        None."""
        if len(data) < self.size:
            return None
        fields = self._struct.unpack_from(data)
        head = len(self._head)
        if fields[:head] != self._head:
            return None
        sec, nanosec = fields[head], fields[head + 1]
        values: list[float] = []
        i = head + 2
        for kind, k in self._tail_plan:
            if kind == "c":
                if fields[i] != self._constants[k]:
                    return None
                i += 1
            else:
                values.extend(fields[i:i + k])
                i += k
        p, v, e = self._value_slices
        return JointStateSample(sec * 1_000_000_000 + nanosec, self.frame_id, self.names,
                                tuple(values[p]), tuple(values[v]), tuple(values[e]))


class JointStateDecoder:
    """Decode a stream of JointState CDR: the layout of the last message is kept as a
    :class:`JointStateCodec`, so that a stream of one layout (every publisher of the
    project's topics) is decoded by it; another layout, or big-endian CDR, goes through
    :func:`decode_joint_state` once per change.

    Raises
    ------
    BagError
        From :meth:`decode`: not a complete JointState CDR (one line).
    """

    def __init__(self) -> None:
        self._codec: JointStateCodec | None = None

    def decode(self, data: bytes | memoryview) -> JointStateSample:
        codec = self._codec
        if codec is not None:
            sample = codec.decode(data)
            if sample is not None:
                return sample
        stamp, layout, (p, v, e), little = _parse(data)
        counts = (p.size, v.size, e.size)
        if little:
            self._codec = JointStateCodec(layout.names, counts, layout.frame_id)
        return JointStateSample(stamp, layout.frame_id, layout.names, tuple(p.tolist()),
                                tuple(v.tolist()), tuple(e.tolist()))


# ------------------------------------------------------------------------------------------
# many messages, numpy


@dataclass(frozen=True)
class JointStates:
    """Decoded JointState messages, one row each.

    Attributes
    ----------
    stamp_ns : ndarray of int64, shape (n,)
        ``header.stamp``.
    position, velocity, effort : ndarray of float64, shape (n, k)
        Values, NaN beyond each message's own count (``k``: the largest count, at least 1).
    counts : ndarray of int64, shape (n, 3)
        Lengths of ``position``, ``velocity``, ``effort`` per message.
    name_sets : tuple of tuple of str
        The distinct ``name`` lists; ``name_id[i]`` indexes the one of message ``i``.
    name_id : ndarray of int64, shape (n,)
    """

    stamp_ns: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    counts: np.ndarray
    name_sets: tuple[tuple[str, ...], ...]
    name_id: np.ndarray

    def __len__(self) -> int:
        return int(self.stamp_ns.size)

    def index_of(self, name: str) -> np.ndarray:
        """Per message: the entry named ``name``, else 0 (how the emulator node picks its
        input, :func:`damper_emulator.ros.emulator.input_sample`)."""
        per_set = np.array([names.index(name) if name in names else 0
                            for names in self.name_sets] or [0], dtype=np.int64)
        index: np.ndarray = per_set[self.name_id]
        return index

    def entry(self, field: str, index: int | np.ndarray) -> np.ndarray:
        """``field[index]`` per message (``index`` a scalar or per-message array); NaN
        where the message has no such entry."""
        values = getattr(self, field)
        rows = np.arange(len(self))
        idx = np.broadcast_to(np.asarray(index, dtype=np.int64), rows.shape)
        out = np.full(len(self), np.nan)
        ok = idx < values.shape[1]
        out[ok] = values[rows[ok], idx[ok]]
        return out

    def has(self, field: str, index: int | np.ndarray) -> np.ndarray:
        """Whether each message has ``field[index]``."""
        k = _FIELDS.index(field)
        return self.counts[:, k] > np.asarray(index)


@plain_kernel
def _gather_rows(buf: NDArray[np.uint8], offsets: NDArray[np.int64],
                 out: NDArray[np.uint8]) -> None:  # pragma: no cover - compiled
    length = out.shape[1]
    for i in range(offsets.size):
        out[i, :] = buf[offsets[i]:offsets[i] + length]


def _gather(buf: np.ndarray, offsets: np.ndarray, length: int) -> np.ndarray:
    """``(n, length)`` uint8 rows ``buf[offsets[i] : offsets[i] + length]``."""
    out = np.empty((offsets.size, length), dtype=np.uint8)
    if length and offsets.size:
        _gather_rows(buf, np.ascontiguousarray(offsets, dtype=np.int64), out)
    return out


def _column(rows: np.ndarray, start: int, dtype: str, count: int = 1) -> np.ndarray:
    width = np.dtype(dtype).itemsize * count
    return np.ascontiguousarray(rows[:, start:start + width]).view(dtype).reshape(-1, count)


def decode_joint_states(buf: bytes | np.ndarray, offsets: np.ndarray,
                        lengths: np.ndarray, where: str = "") -> JointStates:
    """Decode the JointState CDR messages ``buf[offsets[i] : offsets[i] + lengths[i]]``.

    Raises
    ------
    BagError
        A message that is not a complete JointState CDR (one line, prefixed by ``where``
        and naming the message's index).
    """
    arr = np.frombuffer(buf, dtype=np.uint8) if not isinstance(buf, np.ndarray) else buf
    offsets = np.asarray(offsets, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    n = offsets.size
    stamp = np.zeros(n, dtype=np.int64)
    counts = np.zeros((n, 3), dtype=np.int64)
    name_id = np.zeros(n, dtype=np.int64)
    name_sets: dict[tuple[str, ...], int] = {}
    pieces: list[tuple[np.ndarray, tuple[np.ndarray, ...]]] = []  # rows, their values

    def fail(i: int, exc: BagError) -> BagError:
        prefix = f"{where}: " if where else ""
        return BagError(f"{prefix}message {i}: {exc}")

    def one(i: int) -> None:
        lo = int(offsets[i])
        try:
            s, layout, values, _ = _parse(arr[lo:lo + int(lengths[i])].tobytes())
        except BagError as exc:
            raise fail(i, exc) from None
        stamp[i] = s
        name_id[i] = name_sets.setdefault(layout.names, len(name_sets))
        for k, v in enumerate(values):
            counts[i, k] = v.size
        pieces.append((np.array([i]), tuple(v[None, :] for v in values)))

    if n:
        for length in np.unique(lengths):
            members = np.flatnonzero(lengths == length)
            first = int(members[0])
            lo = int(offsets[first])
            try:
                _, layout, _, little = _parse(arr[lo:lo + int(length)].tobytes())
            except BagError as exc:
                raise fail(first, exc) from None
            if not little:
                for i in members:
                    one(int(i))
                continue
            rows = _gather(arr, offsets[members], int(length))
            mask = np.zeros(int(length), dtype=bool)
            for a, b in layout.structural:
                mask[a:b] = True
            same = (rows[:, mask] == rows[0, mask]).all(axis=1)
            for i in members[~same]:
                one(int(i))
            rows, idx = rows[same], members[same]
            sec = _column(rows, 4, "<i4")[:, 0].astype(np.int64)
            nanosec = _column(rows, 8, "<u4")[:, 0].astype(np.int64)
            stamp[idx] = sec * 1_000_000_000 + nanosec
            name_id[idx] = name_sets.setdefault(layout.names, len(name_sets))
            values = []
            for k, (start, count) in enumerate(layout.sequences):
                counts[idx, k] = count
                values.append(_column(rows, start, "<f8", count).astype(float)
                              if count else np.empty((idx.size, 0)))
            pieces.append((idx, tuple(values)))
    width = max(1, int(counts.max()) if n else 1)
    out = [np.full((n, width), np.nan) for _ in _FIELDS]
    for idx, piece in pieces:
        for k, v in enumerate(piece):
            out[k][idx, :v.shape[1]] = v
    return JointStates(stamp, out[0], out[1], out[2], counts,
                       tuple(name_sets), name_id)


def encode_joint_states(stamp_ns: np.ndarray, names: Sequence[str], position: np.ndarray,
                        velocity: np.ndarray, effort: np.ndarray,
                        frame_id: str = "") -> np.ndarray:
    """Many JointStates of one layout as CDR: an ``(n, size)`` uint8 array, one message per
    row (:func:`rows_to_bytes` makes ``bytes`` of them).

    Parameters
    ----------
    stamp_ns : array of int, shape (n,)
    names : sequence of str
        ``name`` of every message.
    position, velocity, effort : array of float, shape (n, k) (``k`` may be 0)
    frame_id : str, optional

    Raises
    ------
    ValueError
        Shapes that do not agree, a stamp outside ``builtin_interfaces/Time``.
    """
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    n = stamp_ns.size
    arrays = []
    for field, values in zip(_FIELDS, (position, velocity, effort)):
        a = np.asarray(values, dtype=float)
        if a.ndim != 2 or a.shape[0] != n:
            raise ValueError(f"{field} must have shape ({n}, k), got {a.shape}")
        arrays.append(a)
    sec, nanosec = _split_stamp(stamp_ns)
    zeros = [np.zeros(a.shape[1]) for a in arrays]
    template = encode_joint_state(0, names, zeros[0], zeros[1], zeros[2], frame_id=frame_id)
    _, layout, _, _ = _parse(template)
    rows = np.tile(np.frombuffer(template, dtype=np.uint8), (n, 1))
    rows[:, 4:8] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
    rows[:, 8:12] = nanosec.astype("<u4").view(np.uint8).reshape(n, 4)
    for (start, count), a in zip(layout.sequences, arrays):
        if count:
            rows[:, start:start + 8 * count] = (
                np.ascontiguousarray(a, dtype="<f8").view(np.uint8).reshape(n, 8 * count))
    return rows


def rows_to_bytes(rows: np.ndarray) -> list[bytes]:
    """One ``bytes`` per row of a uint8 array."""
    n, size = rows.shape
    blob = rows.tobytes()
    return [blob[i:i + size] for i in range(0, n * size, size)]


# ------------------------------------------------------------------------------------------
# raw messages of a bag


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
        _gather_rows(buf, z[:0], np.zeros((0, 1), dtype=np.uint8))


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
