"""The project's CAN database (``config/damper.dbc``): loading, checks and bus load.

The database is read with :mod:`cantools`; this module adds the project's requirements
(the messages the bridge needs, and those of a physical damper in the loop, each with an
alive ``Counter`` and a byte-aligned 8-bit ``Checksum``), the messages' cycle times and
the worst-case bus load of the periodic messages.
"""

from __future__ import annotations

import enum
import math
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import cast

import cantools
from cantools.database.can import Database, Message, Signal

from damper_emulator.errors import UserError, one_line

__all__ = [
    "CHECKSUM_SIGNAL",
    "COUNTER_BITS",
    "COUNTER_CYCLES",
    "COUNTER_SIGNAL",
    "DEFAULT_DBC",
    "HYBRID_SIGNALS",
    "REQUIRED_SIGNALS",
    "DbcError",
    "DynoStatus",
    "ForceStatus",
    "bus_load",
    "check_message",
    "checksum_byte",
    "cycle_time_s",
    "frame_bits",
    "load_database",
    "messages_for",
    "raw_range",
]

#: The project's CAN database.
DEFAULT_DBC = Path(__file__).resolve().parents[1] / "config" / "damper.dbc"

COUNTER_SIGNAL = "Counter"
#: The alive counter's width [bits] and cycle: every message's ``Counter`` counts
#: 0 … ``COUNTER_CYCLES - 1`` and wraps (:func:`check_message` refuses another width).
COUNTER_BITS = 4
COUNTER_CYCLES = 1 << COUNTER_BITS
CHECKSUM_SIGNAL = "Checksum"

#: Messages the bridge needs and their data signals (each also has Counter and Checksum).
REQUIRED_SIGNALS: Mapping[str, tuple[str, ...]] = {
    "DAMPER_STATE": ("Stroke", "Velocity"),
    "DAMPER_FORCE": ("Force", "Status", "InputAge", "StrokeUsed"),
    "VALVE_COMMAND": ("Command",),
    "VEHICLE_MOTION": ("BodyVelocity", "WheelVelocity", "DamperVelocity"),
}

#: Messages of a physical damper in the loop (``damper-hil hybrid``, node ``HYBRID``,
#: and the dyno) and their data signals; ``load_database(required=HYBRID_SIGNALS)``.
#: The database's two uses never share a bus.
HYBRID_SIGNALS: Mapping[str, tuple[str, ...]] = {
    "DYNO_COMMAND": ("StrokeDemand", "VelocityDemand", "Enable"),
    "DYNO_FEEDBACK": ("StrokeMeasured", "Force", "Status"),
    "DYNO_AUX": ("Temperature",),
}


class ForceStatus(enum.IntFlag):
    """Bits of ``DAMPER_FORCE.Status`` (see the signal's comment in the DBC).

    Bits 1..8 are the emulator's (:class:`damper_emulator.realtime.core.Status`), bits
    16..128 the CAN bridge's.
    """

    OK = 0
    NO_INPUT = 1            # emulator: no valid input sample yet
    INPUT_TIMEOUT = 2       # emulator: latest input too old, fault output
    INPUT_REJECTED = 4      # emulator: latest input sample rejected
    MODEL = 8               # emulator: the model flagged the step
    CAN_STATE_TIMEOUT = 16  # bridge: no DAMPER_STATE frame within the timeout
    FORCE_TIMEOUT = 32      # bridge: no /damper/force within the timeout
    CAN_RX_ERRORS = 64      # bridge: CAN receive errors since the last DAMPER_FORCE frame
    FORCE_SATURATED = 128   # bridge: Force saturated to the signal range


class DynoStatus(enum.IntFlag):
    """Bits of ``DYNO_FEEDBACK.Status`` (see the signal's comment in the DBC)."""

    OK = 0
    ENABLED = 1   # following the demand
    AT_LIMIT = 2  # at one of the dyno's own stroke, velocity or force limits
    FAULT = 4     # the dyno reports a fault


class DbcError(UserError):
    """The CAN database cannot be read or lacks what the project needs (one line)."""


#: Payload bytes of the longest CAN frame (CAN FD).
MAX_FRAME_BYTES = 64
#: Longest cycle time [ms]: ``GenMsgCycleTime`` is a 16-bit attribute (INT 0 65535).
MAX_CYCLE_TIME_MS = 65535
#: A number as cantools' DBC parser reads one.
_NUM = r"([-+]?\d+\.?\d*(?:[eE][-+]?\d+)?)"
#: ``BO_ <id> <name>: <length>``
_MESSAGE_LENGTH = re.compile(rf"\bBO_\s+{_NUM}\s+([^\s:]+)\s*:\s*{_NUM}")
#: ``SG_ <name> [<multiplexing>] : <start bit>|<size>@``
_SIGNAL_LAYOUT = re.compile(rf"\bSG_\s+([^\s:]+)(?:\s+[^\s:]+)?\s*:\s*{_NUM}\s*\|\s*{_NUM}\s*@")


def _check_layout_numbers(path: Path) -> None:
    """Refuse a message length, start bit or signal size beyond a CAN frame before cantools
    reads the file: cantools builds lists of a message's bits and codecs in proportion to
    them, so a start bit of 2**32 in a corrupted file takes minutes and gigabytes before it
    is refused (2**20: minutes, quadratic in the start bit).

    Raises
    ------
    DbcError
        One line naming the file, the line and the number.
    """
    text = path.read_text(encoding="cp1252", errors="replace")  # cantools' encoding
    for m in _MESSAGE_LENGTH.finditer(text):
        if not 0 <= float(m.group(3)) <= MAX_FRAME_BYTES:
            line = text.count("\n", 0, m.start()) + 1
            raise DbcError(f"{path}: line {line}: message {m.group(2)} has a length of "
                           f"{m.group(3)} bytes (a CAN frame has 0..{MAX_FRAME_BYTES})")
    for m in _SIGNAL_LAYOUT.finditer(text):
        start, size = float(m.group(2)), float(m.group(3))
        if not (0 <= start < 8 * MAX_FRAME_BYTES and 0 < size <= 8 * MAX_FRAME_BYTES):
            line = text.count("\n", 0, m.start()) + 1
            raise DbcError(f"{path}: line {line}: signal {m.group(1)} at start bit "
                           f"{m.group(2)}, {m.group(3)} bits, is outside any CAN frame "
                           f"(at most {MAX_FRAME_BYTES} bytes)")


def checksum_byte(signal: Signal) -> int | None:
    """Index of the payload byte that holds ``signal``, if it is a byte-aligned 8-bit signal.

    Parameters
    ----------
    signal : cantools.database.can.Signal

    Returns
    -------
    int or None
        The byte index, or None when the signal is not exactly one whole byte.
    """
    if signal.length != 8 or signal.is_float:
        return None
    # cantools keeps the DBC start bit: the LSB for Intel, the MSB for Motorola signals.
    aligned = signal.start % 8 == (0 if signal.byte_order == "little_endian" else 7)
    return signal.start // 8 if aligned else None


def raw_range(signal: Signal) -> tuple[float, float]:
    """The raw values a sender may put in ``signal``: those of its raw type within the DBC
    range ``[minimum|maximum]`` in raw units (a negative scale swaps the ends; a tolerance
    absorbs the decimal rounding of the DBC text, 0.32767 / 1e-5 = 32766.99...).

    Parameters
    ----------
    signal : cantools.database.can.Signal
        With a finite, non-zero scale (:func:`check_message` checks it).

    Returns
    -------
    (float, float)
        ``(lo, hi)``; ``lo > hi`` when the DBC range holds no value of the raw type.
    """
    scale, offset = float(signal.scale), float(signal.offset)
    lo: float
    hi: float
    if signal.is_float:
        lo, hi = -math.inf, math.inf
    elif signal.is_signed:
        lo, hi = -(1 << (signal.length - 1)), (1 << (signal.length - 1)) - 1
    else:
        lo, hi = 0, (1 << signal.length) - 1
    ends = [None if v is None else (v - offset) / scale
            for v in (signal.minimum, signal.maximum)]
    raw_min, raw_max = ends if scale > 0 else ends[::-1]
    # (an end beyond the float range, ±inf, limits nothing or everything: no rounding)
    if raw_min is not None:
        lo = max(lo, raw_min if signal.is_float or math.isinf(raw_min)
                 else math.ceil(raw_min - 1e-6))
    if raw_max is not None:
        hi = min(hi, raw_max if signal.is_float or math.isinf(raw_max)
                 else math.floor(raw_max + 1e-6))
    return lo, hi


def check_message(message: Message, data_signals: Iterable[str] = ()) -> None:
    """Check that ``message`` carries the project's counter and checksum (and data signals),
    and that every signal can be encoded.

    Parameters
    ----------
    message : cantools.database.can.Message
    data_signals : iterable of str
        Further signals the message must have.

    Raises
    ------
    ValueError
        One line naming the message and what is wrong: a signal missing, a counter or
        checksum of the wrong shape, a signal whose scale is 0 or whose scale, offset or
        range is not finite, or whose range ``[minimum|maximum]`` holds no value of its raw
        type (an encoder could send nothing).
    """
    names = {s.name for s in message.signals}
    missing = [n for n in (*data_signals, COUNTER_SIGNAL, CHECKSUM_SIGNAL) if n not in names]
    if missing:
        raise UserError(f"message {message.name} lacks signal(s) {', '.join(missing)}")
    if message.is_container or message.is_multiplexed():
        raise UserError(f"message {message.name}: containers and multiplexing are not "
                         "supported")
    counter = message.get_signal_by_name(COUNTER_SIGNAL)
    if counter.length != COUNTER_BITS or counter.is_signed or counter.is_float:
        raise UserError(f"message {message.name}: {COUNTER_SIGNAL} must be a "
                         f"{COUNTER_BITS}-bit unsigned "
                         f"integer, not {counter.length} bits"
                         f"{' signed' if counter.is_signed else ''}")
    checksum = message.get_signal_by_name(CHECKSUM_SIGNAL)
    index = checksum_byte(checksum)
    if index is None or checksum.is_signed or index >= message.length:
        raise UserError(f"message {message.name}: {CHECKSUM_SIGNAL} must be a byte-aligned "
                         f"unsigned 8-bit signal (start bit {checksum.start}, "
                         f"{checksum.length} bits)")
    for signal in message.signals:
        coding = f"scale {signal.scale}, offset {signal.offset}, range " \
                 f"[{signal.minimum}|{signal.maximum}]"
        if not signal.scale or not all(v is None or math.isfinite(v) for v in (
                signal.scale, signal.offset, signal.minimum, signal.maximum)):
            raise UserError(f"message {message.name}: signal {signal.name} has {coding}: the "
                            "scale must not be 0, all must be finite")
        lo, hi = raw_range(signal)
        if not lo <= hi:
            raise UserError(f"message {message.name}: signal {signal.name} has {coding}, "
                            f"which holds no value of its {signal.length}-bit raw type")


def load_database(path: str | os.PathLike[str] | None = None, *,
                  required: Mapping[str, Iterable[str]] | None = None) -> Database:
    """Read and check a CAN database.

    Parameters
    ----------
    path : path-like, optional
        The DBC file; :data:`DEFAULT_DBC` when None.
    required : mapping of str to iterable of str, optional
        Message name → data signals it must have (besides ``Counter`` and ``Checksum``);
        :data:`REQUIRED_SIGNALS` when None.

    Returns
    -------
    cantools.database.can.Database

    Raises
    ------
    DbcError
        One line naming the file: missing file, parse error, a message length, start bit
        or signal size beyond a CAN frame, a required message or signal missing, a
        required message without a cycle time of 1..65535 ms (``GenMsgCycleTime``: the
        bridge sends at it), or a message :func:`check_message` refuses.
    """
    path = Path(DEFAULT_DBC if path is None else path)
    required = REQUIRED_SIGNALS if required is None else required
    if not path.is_file():
        raise DbcError(f"{path}: no such CAN database file")
    try:
        _check_layout_numbers(path)
    except OSError as exc:
        raise DbcError(f"{path}: cannot read the DBC: {one_line(exc)}") from None
    try:
        # (a DBC file gives a CAN database: cantools types the result of any format)
        db = cast(Database, cantools.database.load_file(path, database_format="dbc",
                                                          strict=True))
    except Exception as exc:  # cantools/textparser raise several unrelated types
        raise DbcError(f"{path}: cannot read the DBC: {one_line(exc)}") from exc
    for name, signals in required.items():
        try:
            message = db.get_message_by_name(name)
        except KeyError:
            raise DbcError(f"{path}: message {name} missing") from None
        try:
            check_message(message, signals)
        except ValueError as exc:
            raise DbcError(f"{path}: {exc}") from None
        ms = message.cycle_time
        if isinstance(ms, bool) or not isinstance(ms, (int, float)) \
                or not 0 < ms <= MAX_CYCLE_TIME_MS:
            raise DbcError(f"{path}: message {name} has no cycle time of 1..{MAX_CYCLE_TIME_MS} "
                           f"ms (GenMsgCycleTime: {ms})")
    return db


def messages_for(db: Database, *, sender: str | None = None,
                 receiver: str | None = None) -> list[str]:
    """Names of the messages a node sends or receives.

    Parameters
    ----------
    db : cantools.database.can.Database
    sender, receiver : str, optional
        Node name (``DYNO``, ``EMULATOR``, ``CONTROLLER``); each given one must match.

    Returns
    -------
    list of str
        Message names in the database's order.
    """
    out = []
    for message in db.messages:
        if sender is not None and sender not in message.senders:
            continue
        if receiver is not None and receiver not in message.receivers:
            continue
        out.append(message.name)
    return out


def cycle_time_s(message: Message) -> float | None:
    """Cycle time of a periodic message (DBC attribute ``GenMsgCycleTime``, ms).

    Returns
    -------
    float or None
        Seconds; None when the message has no (or a zero) cycle time.
    """
    ms = message.cycle_time
    return ms / 1000.0 if ms else None


def frame_bits(dlc: int, extended: bool = False) -> int:
    """Worst-case length on the wire of a classic CAN data frame, in bits.

    Counts the frame with the worst-case bit stuffing and the 3-bit interframe space.
    A standard (11-bit) data frame has 34 + 8·dlc stuffable bits (SOF 1, identifier 11, RTR 1,
    IDE 1, r0 1, DLC 4, data 8·dlc, CRC 15) and 13 fixed-form bits (CRC delimiter 1, ACK 2,
    EOF 7, interframe space 3): 47 + 8·dlc bits.  An extended (29-bit) frame has
    54 + 8·dlc stuffable bits (SOF 1, base identifier 11, SRR 1, IDE 1, identifier extension
    18, RTR 1, r1 1, r0 1, DLC 4, data, CRC 15): 67 + 8·dlc bits.  A stuff bit follows five
    equal bits, and a stuff bit starts the next run, so at most one stuff bit is added for the
    first 5 bits and one per 4 bits after that: ⌊(n − 1)/4⌋ for n stuffable bits.  Hence

        standard:  47 + 8·dlc + ⌊(34 + 8·dlc − 1)/4⌋   (135 bits at dlc 8)
        extended:  67 + 8·dlc + ⌊(54 + 8·dlc − 1)/4⌋   (160 bits at dlc 8)

    Parameters
    ----------
    dlc : int
        Data length, 0..8 bytes.
    extended : bool
        29-bit identifier.

    Returns
    -------
    int
    """
    if isinstance(dlc, bool) or not isinstance(dlc, int) or not 0 <= dlc <= 8:
        raise UserError(f"dlc must be an integer 0..8 (classic CAN), got {dlc!r}")
    stuffable = (54 if extended else 34) + 8 * dlc
    fixed = 13
    return stuffable + fixed + (stuffable - 1) // 4


def bus_load(db: Database, bitrate_bps: float,
             messages: Iterable[str] | None = None) -> float:
    """Worst-case fraction of the bus used by periodic messages.

    ``Σ frame_bits(length) / cycle_time / bitrate`` over the messages.

    Parameters
    ----------
    db : cantools.database.can.Database
    bitrate_bps : float
        Nominal bit rate [bit/s], e.g. 500_000 or 1_000_000.
    messages : iterable of str, optional
        Message names; every message with a cycle time when None.

    Returns
    -------
    float
        Bus load, 1.0 = the whole bus.

    Raises
    ------
    ValueError
        A named message without a cycle time, a CAN FD message, or a non-positive bit rate.
    KeyError
        A named message not in the database.
    """
    if not bitrate_bps > 0:
        raise UserError(f"bitrate_bps must be positive, got {bitrate_bps!r}")
    if messages is None:
        chosen = [m for m in db.messages if cycle_time_s(m)]
    else:
        chosen = [db.get_message_by_name(n) for n in messages]
    bits_per_s = 0.0
    for message in chosen:
        period = cycle_time_s(message)
        if period is None:
            raise UserError(f"message {message.name} has no cycle time (GenMsgCycleTime)")
        if message.is_fd or message.length > 8:
            raise UserError(f"message {message.name}: CAN FD frames are not supported")
        bits_per_s += frame_bits(message.length, message.is_extended_frame) / period
    return bits_per_s / bitrate_bps
