"""Property-based tests of the CAN decoders (``can_bridge``): frames and the database.

Every frame on a CAN bus is untrusted: another node's traffic, a sender with a fault, bit
errors the bus did not catch.  The checks here are the promises of the docstrings, on
random frames (any identifier, the database's among them; 11- or 29-bit; payloads of 0
to 64 bytes; some with a correct checksum, so that the decoding behind it runs; counters
that repeat and jump), against a model of those promises:

* :meth:`Receiver.accept` returns ``(name, values)`` for an accepted frame and None
  for a frame it drops or does not know, and counts each frame exactly once, per message
  and in total: ``unknown_id`` (an identifier not its own, or a 29-bit frame), ``length``,
  ``checksum`` (CRC-8/SAE-J1850 over the other bytes), ``counter`` (equal to the last
  accepted one's), else ``accepted``, with ``lost`` growing by n − 1 on a counter jump of
  n.  An accepted frame's values are every signal of the message, as the DBC's bit layout,
  scale and offset give them (decoded here independently of cantools).
* :meth:`Receiver.decode_values` decodes any payload of a known message without checks
  or counts: the signals the payload holds completely; an unknown identifier or name is a
  KeyError.
* :meth:`BridgeCore.on_frame` turns an accepted ``DAMPER_STATE`` frame (mode dyno) into
  ``("state", stroke, velocity)`` and an accepted ``VALVE_COMMAND`` frame (mode
  controller) into ``("command", c)`` with ``c`` in [0, 1], and anything else into None;
  a dropped frame (or lost frames) sets bit 64, CAN receive errors, in the next
  ``DAMPER_FORCE`` frame's status.
* :func:`load_database` on a corrupted ``config/damper.dbc`` (numbers, names and lines
  changed, text cut, bytes flipped) or random text gives a database or :class:`DbcError`
  (never another exception, never a hang), and a database it gives has what the project
  needs (:class:`DbcError`: "lacks what the project needs"): every required message can
  be encoded (any value: saturated) and received, and the bridge can be built on it.
"""

from __future__ import annotations

import math
import re

import pytest
from fuzz_support import junk_bytes, junk_text, mutated_bytes, time_limit
from hypothesis import given
from hypothesis import strategies as st

from can_bridge import (
    DEFAULT_DBC,
    REQUIRED_SIGNALS,
    DbcError,
    Encoder,
    ForceStatus,
    Receiver,
    crc8_sae_j1850,
    load_database,
)
from can_bridge.core import BridgeCore
from can_bridge.settings import BridgeParams

DB = load_database()
#: the database's messages by (frame id, extended)
MESSAGES = {(m.frame_id, bool(m.is_extended_frame)): m for m in DB.messages}
KNOWN_IDS = sorted(m.frame_id for m in DB.messages)
COUNTER_MASK = 0x0F


def _signal_value(signal, data: bytes) -> float | None:
    """An Intel (little-endian) integer signal's physical value from ``data``, or None
    when ``data`` does not hold all of its bits: the DBC's definition, without cantools."""
    assert signal.byte_order == "little_endian" and not signal.is_float
    if signal.start + signal.length > 8 * len(data):
        return None
    raw = (int.from_bytes(data, "little") >> signal.start) & ((1 << signal.length) - 1)
    if signal.is_signed and raw >> (signal.length - 1):
        raw -= 1 << signal.length
    return raw * signal.scale + signal.offset


def _with_crc(data: bytes) -> bytes:
    """``data`` (8 bytes) with its checksum byte 7 made right."""
    return data[:7] + bytes([crc8_sae_j1850(data[:7])])


@st.composite
def frames(draw: st.DrawFn, extended_ok: bool = True,
           favour: int | None = None) -> tuple[int, bytes, bool]:
    """``(frame_id, data, is_extended_id)``: mostly the database's identifiers (half of
    them ``favour`` when given), 8-byte payloads with a correct checksum and a counter from
    a few values (so that counters repeat and jump); also any identifier, any length
    0..64, a wrong checksum, and (with ``extended_ok``) 29-bit frames."""
    known = st.sampled_from(KNOWN_IDS) if favour is None else \
        st.one_of(st.just(favour), st.sampled_from(KNOWN_IDS))
    frame_id = draw(st.one_of(known, known, st.integers(0, 0x7FF),
                              st.integers(0, 0x1FFFFFFF)))
    extended = extended_ok and draw(st.integers(0, 9)) == 0
    if draw(st.integers(0, 3)) == 0:
        data = draw(st.binary(max_size=64))
    else:
        data = bytearray(draw(st.binary(min_size=8, max_size=8)))
        data[6] = (data[6] & 0xF0) | draw(st.sampled_from((0, 1, 2, 3, 9, 15)))
        data = bytes(data)
        if draw(st.integers(0, 4)) != 0:
            data = _with_crc(data)
    return frame_id, data, extended


class ReceiverModel:
    """What :meth:`Receiver.accept` promises, frame by frame: the outcome and the counts."""

    def __init__(self, names: list[str]) -> None:
        self.known = {(m.frame_id, bool(m.is_extended_frame)): m for m in DB.messages
                      if m.name in names}
        self.last: dict[str, int] = {}
        self.per: dict[str, dict[str, int]] = {n: dict.fromkeys(
            ("accepted", "length", "checksum", "counter", "lost", "unknown_id"), 0)
            for n in names}
        self.total = dict.fromkeys(self.per[names[0]], 0)

    def step(self, frame_id: int, data: bytes, extended: bool) -> tuple[str, str | None]:
        """``(outcome, message name)``; outcome is the counter the frame adds to."""
        message = self.known.get((frame_id, extended))
        if message is None:
            self.total["unknown_id"] += 1
            return "unknown_id", None
        name = message.name
        if len(data) != message.length:
            outcome = "length"
        elif crc8_sae_j1850(data[:7]) != data[7]:
            outcome = "checksum"
        else:
            counter = data[6] & COUNTER_MASK
            last = self.last.get(name)
            step = None if last is None else (counter - last) % 16
            if step == 0:
                outcome = "counter"
            else:
                if step is not None and step > 1:
                    self.per[name]["lost"] += step - 1
                    self.total["lost"] += step - 1
                self.last[name] = counter
                outcome = "accepted"
        self.per[name][outcome] += 1
        self.total[outcome] += 1
        return outcome, name


def check_decoded(got, name: str, data: bytes) -> None:
    """An accepted frame's ``(name, values)``: every signal, as the DBC defines it."""
    got_name, values = got
    assert got_name == name
    message = DB.get_message_by_name(name)
    assert set(values) == {s.name for s in message.signals}
    for signal in message.signals:
        expected = _signal_value(signal, data)
        assert values[signal.name] == pytest.approx(expected, rel=1e-12, abs=1e-12)
        assert math.isfinite(values[signal.name])
    assert values["Counter"] == data[6] & COUNTER_MASK and values["Checksum"] == data[7]


@given(sequence=st.lists(frames(), min_size=20, max_size=60),
       names=st.sampled_from((None, ["DAMPER_STATE"], ["VALVE_COMMAND", "DAMPER_FORCE"])))
def test_receiver_accept(sequence, names):
    """Receiver.accept on random frames: the outcome and the counts its docstring
    promises."""
    rx = Receiver(DB, names)
    model = ReceiverModel(list(rx.names))
    for frame_id, data, extended in sequence:
        with time_limit():
            got = rx.accept(frame_id, data, is_extended_id=extended)
        outcome, name = model.step(frame_id, data, extended)
        if outcome == "accepted":
            assert got is not None
            check_decoded(got, name, data)
        else:
            assert got is None, (outcome, got)
        for n in rx.names:
            counts = rx.counters(n)
            assert {k: getattr(counts, k) for k in model.per[n]} == model.per[n]
            assert rx.last_counter(n) == model.last.get(n)
        assert {k: getattr(rx.drops, k) for k in model.total} == model.total
        assert rx.drops.dropped == sum(model.total[k] for k in ("length", "checksum",
                                                                 "counter"))


@given(frame=frames(), by_name=st.booleans())
def test_receiver_decode_values(frame, by_name):
    """Receiver.decode_values: the signals a payload of a known message holds completely,
    without counting; KeyError for an unknown identifier."""
    frame_id, data, extended = frame
    rx = Receiver(DB)
    message = MESSAGES.get((frame_id, extended))
    if message is None:
        with pytest.raises(KeyError):
            rx.decode_values(frame_id, data, is_extended_id=extended)
        return
    with time_limit():
        values = rx.decode_values(message.name if by_name else frame_id, data,
                                  is_extended_id=extended)
    expected = {s.name: _signal_value(s, data) for s in message.signals}
    assert set(values) == {k for k, v in expected.items() if v is not None}
    for k, v in values.items():
        assert v == pytest.approx(expected[k], rel=1e-12, abs=1e-12)
    assert rx.drops == type(rx.drops)()  # nothing counted


def _force_status(core: BridgeCore, now_ns: int) -> int:
    data = core.force_frame(100.0, 0, 1e-3, 0.0, now_ns)
    return int(DB.get_message_by_name("DAMPER_FORCE").decode(data)["Status"])


@given(mode=st.sampled_from(("dyno", "controller")), data=st.data())
def test_bridge_on_frame(mode, data):
    """BridgeCore.on_frame on random frames (11-bit: the bridge's bus is filtered to its
    own; half of them of its inbound message), with a DAMPER_FORCE frame sent after some:
    the documented result of every frame and the receive-error bit of the force frames."""
    core = BridgeCore(BridgeParams(mode=mode), DB)
    inbound = "DAMPER_STATE" if mode == "dyno" else "VALVE_COMMAND"
    favour = DB.get_message_by_name(inbound).frame_id
    sequence = data.draw(st.lists(st.tuples(frames(extended_ok=False, favour=favour),
                                            st.booleans()), min_size=20, max_size=60),
                         label="frames")
    model = ReceiverModel([inbound])
    trouble = False  # a drop or lost frames since the last DAMPER_FORCE frame
    now_ns, states, commands = 0, 0, 0
    for (frame_id, data, _), send_force in sequence:
        now_ns += 1_000_000
        with time_limit():
            got = core.on_frame(frame_id, data, now_ns)
        lost_before = model.total["lost"]
        outcome, _name = model.step(frame_id, data, False)
        trouble |= outcome in ("length", "checksum", "counter") \
            or model.total["lost"] > lost_before
        if outcome != "accepted":
            assert got is None
        elif mode == "dyno":
            states += 1
            kind, stroke, velocity = got
            sig = DB.get_message_by_name(inbound)
            assert kind == "state"
            assert stroke == pytest.approx(_signal_value(sig.get_signal_by_name("Stroke"),
                                                         data), rel=1e-12, abs=1e-12)
            assert velocity == pytest.approx(
                _signal_value(sig.get_signal_by_name("Velocity"), data), rel=1e-12,
                abs=1e-12)
        else:
            commands += 1
            kind, command = got
            raw = _signal_value(DB.get_message_by_name(inbound).get_signal_by_name("Command"),
                                data)
            assert kind == "command"
            assert command == pytest.approx(min(max(raw, 0.0), 1.0), abs=1e-12)
            assert 0.0 <= command <= 1.0 and core.command == command
        assert (core.counters.states_in, core.counters.commands_in) == (states, commands)
        if send_force:
            status = _force_status(core, now_ns)
            assert bool(status & ForceStatus.CAN_RX_ERRORS) == trouble
            trouble = False


# ---- the database ---------------------------------------------------------------------

DBC_TEXT = DEFAULT_DBC.read_bytes()
#: a number of the DBC (identifier, length, start bit, size, scale, offset, range, ...)
_NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
#: a name the project's checks look for
_NAME = re.compile(rb"\b(?:DAMPER_STATE|DAMPER_FORCE|VALVE_COMMAND|VEHICLE_MOTION|Counter|"
                   rb"Checksum|Stroke|Velocity|Force|Command|GenMsgCycleTime|EMULATOR|DYNO)\b")

number_texts = st.one_of(
    st.integers(-2**40, 2**40).map(str), st.integers(0, 70).map(str),
    st.floats(allow_nan=False).map(repr),
    st.sampled_from(("0", "-1", "1E-300", "1E+300", "1e999", "nan", "inf", "", "-", "0.0",
                     "4294967296", "536870911", "2147483648", "99999999999999999999999")),
)


@st.composite
def dbc_files(draw: st.DrawFn) -> bytes:
    """``config/damper.dbc`` with numbers, names or lines changed, bytes changed, or
    random bytes and text."""
    kind = draw(st.sampled_from(("number", "number", "number", "name", "line", "bytes",
                                 "junk")))
    text = DBC_TEXT
    if kind == "junk":
        return draw(junk_bytes | junk_text.map(lambda s: s.encode("utf-8")))
    if kind == "bytes":
        return draw(mutated_bytes(text))
    for _ in range(draw(st.integers(1, 3))):
        numbers = [m.span() for m in _NUMBER.finditer(text)]
        names = [m.span() for m in _NAME.finditer(text)]
        if kind == "number" and numbers:
            start, end = draw(st.sampled_from(numbers))
            text = text[:start] + draw(number_texts).encode() + text[end:]
        elif kind == "name" and names:
            start, end = draw(st.sampled_from(names))
            new = draw(st.sampled_from((b"Counter", b"Checksum", b"X", b"", b"DAMPER_STATE"))
                       | st.text("ABCXYZ_019", max_size=6).map(str.encode))
            text = text[:start] + new + text[end:]
        else:
            lines = text.splitlines(keepends=True)
            i = draw(st.integers(0, len(lines) - 1))
            op = draw(st.sampled_from(("delete", "duplicate", "swap")))
            if op == "delete":
                del lines[i]
            elif op == "duplicate":
                lines.insert(i, lines[i])
            else:
                j = draw(st.integers(0, len(lines) - 1))
                lines[i], lines[j] = lines[j], lines[i]
            text = b"".join(lines)
    return text


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_can")


def check_usable(db) -> None:
    """What a database from load_database must allow: an encoder and a receiver of every
    required message (frames of any value, the first one accepted), and the bridge in both
    modes (its force, fault and motion frames, an inbound frame)."""
    for name, signals in REQUIRED_SIGNALS.items():
        encoder = Encoder(db, name)
        assert set(signals) <= set(encoder.signal_names)
        rx = Receiver(db, [name])
        for value in (0.0, 1e9, -1e9, math.inf, -math.inf):
            data, _ = encoder.encode(**dict.fromkeys(encoder.signal_names, value))
            assert len(data) == encoder.length
            if value == 0.0:
                assert rx.accept(encoder.frame_id, data, encoder.is_extended_id) is not None
    for mode, inbound in (("dyno", "DAMPER_STATE"), ("controller", "VALVE_COMMAND")):
        core = BridgeCore(BridgeParams(mode=mode), db)
        core.force_frame(1e9, 0, 1e-3, 0.0, 0)
        core.watchdog(10**9)
        core.motion_frame(1.0, -1.0, 2.0, 0)
        encoder = Encoder(db, inbound)
        data, _ = encoder.encode(**dict.fromkeys(encoder.signal_names, 0.5))
        core.on_frame(encoder.frame_id, data, 0)


@given(blob=dbc_files())
def test_load_database_corrupted(workdir, blob):
    """load_database on a corrupted or random DBC: DbcError, or a database the codec and
    the bridge can use."""
    path = workdir / "damper.dbc"
    path.write_bytes(blob)
    try:
        with time_limit():
            db = load_database(path)
    except DbcError as exc:
        assert str(path) in str(exc)
        return
    check_usable(db)


def _a_log(suffix: str) -> bytes:
    """A small valid CAN log of a dyno and the emulator, by python-can's writer."""
    import tempfile
    from pathlib import Path

    import can

    db = load_database()
    state, force = Encoder(db, "DAMPER_STATE"), Encoder(db, "DAMPER_FORCE")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"log{suffix}"
        with can.Logger(path) as writer:
            for i in range(40):
                x = 0.01 * math.sin(i / 6.0)
                for enc, values, rx in ((state, {"Stroke": x, "Velocity": 0.1}, True),
                                        (force, {"Force": 100.0 * x, "Status": 0,
                                                 "InputAge": 0.0, "StrokeUsed": x}, False)):
                    data, _ = enc.encode(**values)
                    writer.on_message_received(can.Message(
                        timestamp=1.7e9 + i * 1e-3 + (0 if rx else 3e-4),
                        arbitration_id=enc.frame_id, data=data, is_extended_id=False,
                        is_rx=rx))
        return path.read_bytes()


@st.composite
def can_logs(draw):
    suffix = draw(st.sampled_from((".blf", ".asc")))
    kind = draw(st.sampled_from(("junk", "mutated", "mutated", "text")))
    if kind == "junk":
        return suffix, draw(junk_bytes)
    if kind == "text":
        return suffix, draw(junk_text).encode("utf-8", "surrogatepass")
    return suffix, draw(mutated_bytes(_LOGS.setdefault(suffix, _a_log(suffix))))


_LOGS: dict[str, bytes] = {}


@given(log=can_logs())
def test_can_log_any_bytes(workdir, log):
    """read_can_log (replay's CAN input) on random or damaged BLF and ASC files: the
    replay's input, or one line of CanLogError naming the file; never another exception,
    never a hang."""
    from can_bridge.can_log import CanLogError
    from can_bridge.log_input import read_can_log

    suffix, blob = log
    path = workdir / f"run{suffix}"
    path.write_bytes(blob)
    try:
        with time_limit():
            data, info = read_can_log(path)
    except CanLogError as exc:
        assert str(path) in str(exc) and "\n" not in str(exc)
        return
    assert info["kind"] in ("emulator", "damper")
    assert len(data.state) >= 1 and len(data.force) >= 1
