"""Frame codec of ``config/damper.dbc``, separate from any bus.

:class:`Encoder` turns physical values into the payload of one message, with the alive
counter and the CRC filled in and out-of-range values saturated.  :class:`Receiver` checks
and decodes the payloads of a set of messages, dropping (and counting) frames with a wrong
length, a wrong checksum or a counter that did not advance.  Both work on ``(frame_id,
bytes)``; :mod:`can_bridge.bus` moves them over python-can.

Examples
--------
>>> from can_bridge import load_database, Encoder, Receiver
>>> db = load_database()
>>> enc = Encoder(db, "DAMPER_STATE")
>>> data, saturated = enc.encode(Stroke=0.0123, Velocity=-0.5)
>>> rx = Receiver(db, ["DAMPER_STATE"])
>>> name, values = rx.accept(enc.frame_id, data)
>>> name, round(values["Stroke"], 5), values["Counter"]
('DAMPER_STATE', 0.0123, 0)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, NamedTuple, cast

from cantools.database.can import Database, Message

from can_bridge.crc import crc8_sae_j1850
from can_bridge.dbc import (
    CHECKSUM_SIGNAL,
    COUNTER_CYCLES,
    COUNTER_SIGNAL,
    check_message,
    checksum_byte,
    cycle_time_s,
    raw_range,
)

__all__ = ["Decoded", "EncodedFrame", "Encoder", "FrameCounters", "Receiver"]


class EncodedFrame(NamedTuple):
    """What :meth:`Encoder.encode` returns; unpacks as ``data, saturated``."""

    #: The payload, ``Encoder.length`` bytes, counter and checksum filled in.
    data: bytes
    #: Names of the signals whose value was outside the signal's range and was sent
    #: saturated to it (in the message's signal order); empty when none was.
    saturated: tuple[str, ...]


class Decoded(NamedTuple):
    """What :meth:`Receiver.accept` returns for an accepted frame; unpacks as ``name, values``."""

    #: Message name.
    name: str
    #: Physical value of every signal of the message (``Counter`` and ``Checksum`` included,
    #: as raw integers), by signal name.
    values: dict[str, float | int]


@dataclass
class FrameCounters:
    """Frame counts of a :class:`Receiver`, per message or in total.

    Attributes
    ----------
    accepted : int
        Frames accepted and decoded.
    length : int
        Dropped: payload length not the message's length.
    checksum : int
        Dropped: CRC mismatch.
    counter : int
        Dropped: counter equal to the previous accepted frame's (did not advance).
    lost : int
        Frames missing before accepted frames whose counter jumped by more than one (a jump of
        n counts n − 1).  Not a drop: those frames never arrived.
    unknown_id : int
        Frames handed to :meth:`Receiver.accept` with an identifier not in the receiver's
        set (only in the total; not an error: other nodes' traffic).  Behind a bus
        filtered to :attr:`Receiver.frame_ids` (``BusConfig.receive_ids``, as the bridge,
        the loopback dyno and the skyhook controller open theirs) such frames never reach
        the receiver and this stays 0.
    """

    accepted: int = 0
    length: int = 0
    checksum: int = 0
    counter: int = 0
    lost: int = 0
    unknown_id: int = 0

    @property
    def dropped(self) -> int:
        """Frames dropped as invalid: ``length + checksum + counter``."""
        return self.length + self.checksum + self.counter

    def copy(self) -> FrameCounters:
        """An independent copy (a snapshot for diagnostics)."""
        return dataclasses.replace(self)


@dataclass(frozen=True)
class _SignalCoding:
    name: str
    scale: float
    offset: float
    raw_lo: float
    raw_hi: float
    is_float: bool


def _signal_coding(signal: Any) -> _SignalCoding:
    lo, hi = raw_range(signal)
    return _SignalCoding(signal.name, float(signal.scale), float(signal.offset), lo, hi,
                         bool(signal.is_float))


#: decoded signal values by name (numbers: decoded without choices)
_Values = dict[str, float | int]


def _get_message(db: Database, name: str) -> Message:
    try:
        return db.get_message_by_name(name)
    except KeyError:
        raise KeyError(f"message {name} not in the CAN database") from None


class Encoder:
    """Encoder of one message: physical values in, payload out.

    The encoder owns the message's alive counter: the first frame carries ``Counter`` 0, each
    further frame one more, modulo 16.  The checksum (CRC-8/SAE-J1850) covers every payload
    byte but the checksum byte, in order (bytes 0..6 for the project's messages).  Unused
    bits are 0.  Not thread-safe: use one encoder per sending thread.

    Parameters
    ----------
    db : cantools.database.can.Database
        The database (see :func:`can_bridge.dbc.load_database`).
    name : str
        Message name, e.g. ``"DAMPER_FORCE"``.

    Raises
    ------
    KeyError
        No such message.
    ValueError
        The message lacks a 4-bit ``Counter`` or a byte-aligned 8-bit ``Checksum``.
    """

    def __init__(self, db: Database, name: str) -> None:
        message = _get_message(db, name)
        check_message(message)
        self._message = message
        self.name: str = message.name
        self.frame_id: int = message.frame_id
        self.is_extended_id: bool = bool(message.is_extended_frame)
        self.length: int = message.length
        self.cycle_time_s: float | None = cycle_time_s(message)
        self._codings = tuple(_signal_coding(s) for s in message.signals
                              if s.name not in (COUNTER_SIGNAL, CHECKSUM_SIGNAL))
        #: Data signal names, in the message's order (the keyword arguments of :meth:`encode`).
        self.signal_names: tuple[str, ...] = tuple(c.name for c in self._codings)
        # (an int: check_message() above refuses a checksum without a byte of its own)
        self._crc_index = cast(int, checksum_byte(message.get_signal_by_name(CHECKSUM_SIGNAL)))
        self._counter = 0
        #: Frames encoded so far.
        self.frames: int = 0
        #: Frames in which at least one value was saturated.
        self.saturated_frames: int = 0

    @property
    def counter(self) -> int:
        """The ``Counter`` value the next frame will carry."""
        return self._counter

    def reset(self) -> None:
        """Restart the alive counter at 0 (as after a power cycle of the sender)."""
        self._counter = 0

    def encode(self, **values: float) -> EncodedFrame:
        """Payload of the next frame.

        Parameters
        ----------
        **values : float
            The physical value of every data signal (all of :attr:`signal_names`; not
            ``Counter`` or ``Checksum``), in the signal's unit.  A value outside the signal's
            range (DBC ``[min|max]``, within the raw integer type) is saturated to it; ±inf
            saturates too.

        Returns
        -------
        EncodedFrame
            ``(data, saturated)``: the payload and the names of the saturated signals.

        Raises
        ------
        ValueError
            A missing, unknown or NaN value (one line; the counter does not advance).
        """
        if len(values) != len(self._codings) or any(k not in values
                                                    for k in self.signal_names):
            missing = [n for n in self.signal_names if n not in values]
            unknown = [k for k in values if k not in self.signal_names]
            parts = []
            if missing:
                parts.append(f"missing {', '.join(missing)}")
            if unknown:
                parts.append(f"unknown {', '.join(unknown)}")
            raise ValueError(f"{self.name}: {'; '.join(parts)} (signals: "
                             f"{', '.join(self.signal_names)})")
        raw: dict[str, float | int] = {}
        saturated: list[str] = []
        for c in self._codings:
            value = float(values[c.name])
            if math.isnan(value):
                raise ValueError(f"{self.name}.{c.name}: value is NaN")
            if c.is_float:
                r: float | int = (value - c.offset) / c.scale
            else:
                scaled = (value - c.offset) / c.scale
                r = round(scaled) if math.isfinite(scaled) else (c.raw_hi if scaled > 0
                                                                else c.raw_lo)
            if r < c.raw_lo:
                r = c.raw_lo
                saturated.append(c.name)
            elif r > c.raw_hi:
                r = c.raw_hi
                saturated.append(c.name)
            elif not math.isfinite(value):
                saturated.append(c.name)
            raw[c.name] = r
        raw[COUNTER_SIGNAL] = self._counter
        raw[CHECKSUM_SIGNAL] = 0
        data = bytearray(self._message.encode(raw, scaling=False, padding=False,
                                              strict=False))
        i = self._crc_index
        data[i] = crc8_sae_j1850(data[:i] + data[i + 1:])
        self._counter = (self._counter + 1) % COUNTER_CYCLES
        self.frames += 1
        if saturated:
            self.saturated_frames += 1
        return EncodedFrame(bytes(data), tuple(saturated))


class _RxMessage:
    __slots__ = ("counters", "crc_index", "last_counter", "message")

    def __init__(self, message: Message) -> None:
        self.message = message
        # (an int: the Receiver has run check_message() on the message)
        self.crc_index = cast(int, checksum_byte(message.get_signal_by_name(CHECKSUM_SIGNAL)))
        self.counters = FrameCounters()
        self.last_counter: int | None = None


class Receiver:
    """Checking decoder of a set of messages, by frame identifier.

    A frame is accepted when its identifier is one of the set's, its length is the
    message's, its checksum matches (CRC-8/SAE-J1850 over the other payload bytes) and its
    counter differs from the previous accepted frame's of the same message.  A counter jump
    of n > 1 is accepted and counts n − 1 ``lost`` frames.  The first frame of a message
    (and the first after :meth:`forget_counters`) is accepted with any counter.  Every
    outcome is counted per message (:meth:`counters`) and in total (:attr:`drops`), as
    :class:`FrameCounters`.

    One thread calls :meth:`accept`; other threads may read the counters (take
    :meth:`FrameCounters.copy` snapshots for a consistent view).

    Parameters
    ----------
    db : cantools.database.can.Database
    names : iterable of str, optional
        Messages to accept; all of the database's when None.  Frames of other messages that
        reach :meth:`accept` count as ``unknown_id`` (e.g. the node's own frames echoed back
        on an unfiltered ``udp_multicast`` bus): pick the messages the node receives, e.g.
        ``messages_for(db, receiver="EMULATOR")``.

    Raises
    ------
    KeyError
        A name not in the database.
    ValueError
        A message without a 4-bit ``Counter`` or a byte-aligned 8-bit ``Checksum``.
    """

    def __init__(self, db: Database, names: Iterable[str] | None = None) -> None:
        messages = (list(db.messages) if names is None
                    else [_get_message(db, n) for n in names])
        self._by_id: dict[tuple[int, bool], _RxMessage] = {}
        self._by_name: dict[str, _RxMessage] = {}
        for message in messages:
            check_message(message)
            rx = _RxMessage(message)
            self._by_id[(message.frame_id, bool(message.is_extended_frame))] = rx
            self._by_name[message.name] = rx
        #: Totals over all messages, ``unknown_id`` included (also :attr:`total`).
        self.drops = FrameCounters()

    @property
    def total(self) -> FrameCounters:
        """The live totals, the same object as :attr:`drops`."""
        return self.drops

    @property
    def names(self) -> tuple[str, ...]:
        """The messages this receiver accepts."""
        return tuple(self._by_name)

    @property
    def frame_ids(self) -> tuple[int, ...]:
        """The 11-bit identifiers of the standard-frame messages it accepts (for
        :attr:`can_bridge.bus.BusConfig.receive_ids`)."""
        return tuple(fid for fid, extended in self._by_id if not extended)

    def counters(self, name: str) -> FrameCounters:
        """The live counters of one message (``unknown_id`` is always 0 there)."""
        return self._rx(name).counters

    def last_counter(self, name: str) -> int | None:
        """``Counter`` of the last accepted frame of ``name`` (None: none yet)."""
        return self._rx(name).last_counter

    def forget_counters(self, name: str | None = None) -> None:
        """Accept the next frame of ``name`` (of every message when None) with any counter.

        For a known gap, e.g. after the bus was reopened: the frame count of a long gap is
        unknowable modulo 16.
        """
        for rx in ([self._rx(name)] if name is not None else self._by_name.values()):
            rx.last_counter = None

    def _rx(self, name: str) -> _RxMessage:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"message {name} not in this receiver "
                           f"({', '.join(self._by_name)})") from None

    def accept(self, frame_id: int, data: bytes | bytearray,
               is_extended_id: bool = False) -> Decoded | None:
        """Check and decode one frame.

        Parameters
        ----------
        frame_id : int
            Arbitration identifier.
        data : bytes-like
            Payload.
        is_extended_id : bool
            29-bit identifier (a 29-bit frame never matches an 11-bit message).

        Returns
        -------
        Decoded or None
            ``(name, values)`` of an accepted frame; None for a dropped frame or an unknown
            identifier (see the counters).
        """
        total = self.drops
        rx = self._by_id.get((frame_id, bool(is_extended_id)))
        if rx is None:
            total.unknown_id += 1
            return None
        counts = rx.counters
        message = rx.message
        if len(data) != message.length:
            counts.length += 1
            total.length += 1
            return None
        data = bytes(data)
        i = rx.crc_index
        if crc8_sae_j1850(data[:i] + data[i + 1:]) != data[i]:
            counts.checksum += 1
            total.checksum += 1
            return None
        # (the signal values: cantools types decode() with its container form too)
        values = cast(_Values, message.decode(data, decode_choices=False, scaling=True))
        counter = int(values[COUNTER_SIGNAL])
        last = rx.last_counter
        if last is not None:
            step = (counter - last) % COUNTER_CYCLES
            if step == 0:
                counts.counter += 1
                total.counter += 1
                return None
            if step > 1:
                counts.lost += step - 1
                total.lost += step - 1
        rx.last_counter = counter
        counts.accepted += 1
        total.accepted += 1
        return Decoded(message.name, values)

    def decode_values(self, message: int | str, data: bytes | bytearray,
                      is_extended_id: bool = False) -> dict[str, float | int]:
        """Decode a payload without any check and without counting (for tools).

        Parameters
        ----------
        message : int or str
            Frame identifier or message name.
        data : bytes-like
            Payload; a short one decodes the signals it holds completely.
        is_extended_id : bool
            With an integer ``message``: 29-bit identifier.

        Returns
        -------
        dict
            Physical values by signal name.

        Raises
        ------
        KeyError
            Unknown identifier or name.
        """
        rx: _RxMessage | None
        if isinstance(message, str):
            rx = self._rx(message)
        else:
            rx = self._by_id.get((message, bool(is_extended_id)))
            if rx is None:
                raise KeyError(f"frame id 0x{message:X} not in this receiver")
        return dict(cast(_Values, rx.message.decode(bytes(data), decode_choices=False,
                                                    scaling=True, allow_truncated=True)))
