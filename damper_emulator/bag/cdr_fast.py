"""Fast columnar access to ``sensor_msgs/msg/JointState`` topics of a bag, without rclpy and
without per-message rosbags objects.

Two parts, used by the offline replay (:mod:`damper_emulator.replay`) with
:func:`damper_emulator.bag.raw_topics.read_raw`:

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

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.model.jit import plain_kernel

from .messages import BagError

__all__ = [
    "JointStateCodec",
    "JointStateDecoder",
    "JointStateSample",
    "JointStates",
    "decode_joint_state",
    "decode_joint_states",
    "encode_joint_state",
    "encode_joint_states",
    "gather_rows",
    "rows_to_bytes",
]

JOINT_STATE = "sensor_msgs/msg/JointState"
_FIELDS = ("position", "velocity", "effort")


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
def gather_rows(buf: NDArray[np.uint8], offsets: NDArray[np.int64],
                 out: NDArray[np.uint8]) -> None:  # pragma: no cover - compiled
    length = out.shape[1]
    for i in range(offsets.size):
        out[i, :] = buf[offsets[i]:offsets[i] + length]


def _gather(buf: np.ndarray, offsets: np.ndarray, length: int) -> np.ndarray:
    """``(n, length)`` uint8 rows ``buf[offsets[i] : offsets[i] + length]``."""
    out = np.empty((offsets.size, length), dtype=np.uint8)
    if length and offsets.size:
        gather_rows(buf, np.ascontiguousarray(offsets, dtype=np.int64), out)
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
