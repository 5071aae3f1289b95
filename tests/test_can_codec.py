"""CAN layer without a bus: CRC, DBC, encoder and checking receiver."""

import random

import cantools
import pytest

from can_bridge import (
    DEFAULT_DBC,
    HYBRID_SIGNALS,
    REQUIRED_SIGNALS,
    DbcError,
    DynoStatus,
    Encoder,
    FrameCounters,
    Receiver,
    bus_load,
    crc8_sae_j1850,
    cycle_time_s,
    frame_bits,
    load_database,
    messages_for,
)

MESSAGES = {  # name: (frame id, cycle [s], {signal: (unit, min, max, step)})
    "DAMPER_STATE": (0x100, 0.001, {"Stroke": ("m", -0.32768, 0.32767, 1e-5),
                                    "Velocity": ("m/s", -6.5536, 6.5534, 2e-4)}),
    "DAMPER_FORCE": (0x101, 0.001, {"Force": ("N", -16384, 16383.5, 0.5),
                                    "Status": (None, 0, 255, 1),
                                    "InputAge": ("s", 0, 0.0255, 1e-4),
                                    "StrokeUsed": ("m", -0.32768, 0.32767, 1e-5)}),
    "VALVE_COMMAND": (0x110, 0.005, {"Command": (None, 0, 1, 1e-4)}),
    "VEHICLE_MOTION": (0x120, 0.005, {"BodyVelocity": ("m/s", -3.2768, 3.2767, 1e-4),
                                      "WheelVelocity": ("m/s", -6.5536, 6.5534, 2e-4),
                                      "DamperVelocity": ("m/s", -6.5536, 6.5534, 2e-4)}),
    # a physical damper in the loop: stroke within 10 um, force within 0.5 N
    "DYNO_COMMAND": (0x140, 0.001, {"StrokeDemand": ("m", -0.32768, 0.32767, 1e-5),
                                    "VelocityDemand": ("m/s", -6.5536, 6.5534, 2e-4),
                                    "Enable": (None, 0, 1, 1)}),
    "DYNO_FEEDBACK": (0x141, 0.001, {"StrokeMeasured": ("m", -0.32768, 0.32767, 1e-5),
                                     "Force": ("N", -16384, 16383.5, 0.5),
                                     "Status": (None, 0, 255, 1)}),
    "DYNO_AUX": (0x148, 0.1, {"Temperature": ("degC", -327.68, 327.67, 0.01)}),
}


def crc8_bitwise(data):
    """Independent reference: bit-by-bit CRC-8, poly 0x1D, init 0xFF, xorout 0xFF."""
    crc = 0xFF
    for byte in data:
        for i in range(7, -1, -1):
            bit = (byte >> i) & 1
            top = (crc >> 7) & 1
            crc = (crc << 1) & 0xFF
            if top ^ bit:
                crc ^= 0x1D
    return crc ^ 0xFF


@pytest.fixture(scope="module")
def db():
    return load_database()


# -- CRC ---------------------------------------------------------------------------------
def test_crc_catalogue_check_value():
    assert crc8_sae_j1850(b"123456789") == 0x4B      # reveng catalogue, CRC-8/SAE-J1850
    assert crc8_sae_j1850(b"") == 0x00               # init 0xFF xor 0xFF


def test_crc_matches_bitwise_reference():
    rng = random.Random(6)
    for n in [*range(12), 64, 257]:
        for _ in range(20):
            data = bytes(rng.randrange(256) for _ in range(n))
            assert crc8_sae_j1850(data) == crc8_bitwise(data)
    assert crc8_bitwise(b"123456789") == 0x4B


# -- DBC ---------------------------------------------------------------------------------
def test_dbc_read_by_cantools_directly():
    db = cantools.database.load_file(DEFAULT_DBC, strict=True)
    assert {m.name for m in db.messages} >= set(MESSAGES)
    assert {n.name for n in db.nodes} == {"DYNO", "EMULATOR", "CONTROLLER", "HYBRID"}


def test_dbc_layout_units_ranges_cycle_times(db):
    for name, (frame_id, cycle, signals) in MESSAGES.items():
        m = db.get_message_by_name(name)
        assert m.frame_id == frame_id and not m.is_extended_frame and m.length == 8
        assert cycle_time_s(m) == pytest.approx(cycle)
        assert m.comment
        for sig, (unit, lo, hi, step) in signals.items():
            s = m.get_signal_by_name(sig)
            assert s.byte_order == "little_endian"
            assert s.unit == unit
            assert (s.minimum, s.maximum) == (pytest.approx(lo), pytest.approx(hi))
            assert s.scale == pytest.approx(step)
            assert s.comment
        counter = m.get_signal_by_name("Counter")
        assert (counter.start, counter.length, counter.is_signed) == (48, 4, False)
        checksum = m.get_signal_by_name("Checksum")
        assert (checksum.start, checksum.length, checksum.is_signed) == (56, 8, False)
    assert db.get_message_by_name("DAMPER_STATE").senders == ["DYNO"]
    assert db.get_message_by_name("DAMPER_FORCE").receivers == {"DYNO", "CONTROLLER"}
    assert messages_for(db, receiver="EMULATOR") == ["DAMPER_STATE", "VALVE_COMMAND"]
    assert messages_for(db, sender="EMULATOR") == ["DAMPER_FORCE", "VEHICLE_MOTION"]
    assert messages_for(db, sender="HYBRID") == ["DYNO_COMMAND"]
    assert messages_for(db, receiver="HYBRID") == ["DYNO_FEEDBACK", "DYNO_AUX"]
    assert set(HYBRID_SIGNALS) == set(messages_for(db, sender="HYBRID")
                                      + messages_for(db, receiver="HYBRID"))
    # the damper in the loop's messages as its command loads them
    hybrid = load_database(required=HYBRID_SIGNALS)
    for name, signals in HYBRID_SIGNALS.items():
        assert set(signals) == set(MESSAGES[name][2])
        assert hybrid.get_message_by_name(name).frame_id == MESSAGES[name][0]
    # DYNO_FEEDBACK.Status: the contract's bits
    assert (DynoStatus.ENABLED, DynoStatus.AT_LIMIT, DynoStatus.FAULT) == (1, 2, 4)
    text = DEFAULT_DBC.read_text()
    assert "CRC-8/SAE-J1850" in text and "alive counter" in text


def test_dbc_errors_are_one_line_and_name_the_file(tmp_path):
    missing = tmp_path / "nope.dbc"
    with pytest.raises(DbcError, match=r"nope\.dbc") as err:
        load_database(missing)
    assert "\n" not in str(err.value)

    bad = tmp_path / "bad.dbc"
    bad.write_text('BO_ 256 X: 8 A\n SG_ S : 0|16@1- (1,0 [0|1] "" B\n')
    with pytest.raises(DbcError, match=r"bad\.dbc.*cannot read") as err:
        load_database(bad)
    assert "\n" not in str(err.value)

    text = DEFAULT_DBC.read_text()
    no_checksum = tmp_path / "no_checksum.dbc"
    no_checksum.write_text(text.replace(
        ' SG_ Checksum : 56|8@1+ (1,0) [0|255] "" EMULATOR\n\nBO_ 257', '\nBO_ 257'))
    with pytest.raises(DbcError, match=r"no_checksum\.dbc: message DAMPER_STATE lacks "
                                       r"signal.*Checksum"):
        load_database(no_checksum)

    no_message = tmp_path / "no_message.dbc"
    no_message.write_text(text.replace("VEHICLE_MOTION", "OTHER_MOTION"))
    with pytest.raises(DbcError, match=r"no_message\.dbc: message VEHICLE_MOTION missing"):
        load_database(no_message)

    shifted = tmp_path / "shifted.dbc"
    shifted.write_text(text.replace(' SG_ Checksum : 56|8@1+ (1,0) [0|255] "" EMULATOR\n\n'
                                    'BO_ 257', ' SG_ Checksum : 52|8@1+ (1,0) [0|255] "" '
                                    'EMULATOR\n\nBO_ 257', 1))
    with pytest.raises(DbcError, match="byte-aligned"):
        load_database(shifted)


def test_frame_bits_and_bus_load(db):
    # standard frame, 8 bytes: 34 + 64 stuffable bits -> 24 stuff bits; 47 + 64 fixed
    assert frame_bits(8) == 135
    assert frame_bits(0) == 47 + 8
    assert frame_bits(8, extended=True) == 67 + 64 + (54 + 64 - 1) // 4 == 160
    with pytest.raises(ValueError, match=r"dlc must be an integer 0\.\.8"):
        frame_bits(9)
    # by hand: two 1 ms and two 5 ms messages of 135 bits
    bits_per_s = 135 / 0.001 * 2 + 135 / 0.005 * 2
    assert bits_per_s == pytest.approx(324_000)
    assert bus_load(db, 500_000, REQUIRED_SIGNALS) == pytest.approx(0.648)
    assert bus_load(db, 1_000_000, REQUIRED_SIGNALS) == pytest.approx(0.324)
    assert bus_load(db, 500_000, ["DAMPER_STATE"]) == pytest.approx(0.27)
    # the damper in the loop: two 1 ms messages and one of 100 ms
    assert bus_load(db, 1_000_000, HYBRID_SIGNALS) == pytest.approx(
        (135 / 0.001 * 2 + 135 / 0.1) / 1e6)
    # the database's comment states both (its two uses never share a bus)
    text = DEFAULT_DBC.read_text()
    assert "324 kbit/s, 64.8 % at 500 kbit/s, 32.4 % at 1 Mbit/s" in text
    assert "271.35 kbit/s, 54.3 % at 500 kbit/s, 27.1 % at 1 Mbit/s" in text


# -- codec -------------------------------------------------------------------------------
def _random_values(rng, signals, margin=0.999):
    return {sig: (rng.randint(lo, hi) if step == 1
                  else rng.uniform(lo * margin, hi * margin))
            for sig, (_u, lo, hi, step) in signals.items()}


def test_round_trip_every_message(db):
    rng = random.Random(1)
    rx = Receiver(db)
    for name, (frame_id, _cycle, signals) in MESSAGES.items():
        enc = Encoder(db, name)
        assert (enc.name, enc.frame_id, enc.length) == (name, frame_id, 8)
        assert set(enc.signal_names) == set(signals)
        for _ in range(50):
            values = _random_values(rng, signals)
            data, saturated = enc.encode(**values)
            assert saturated == () and len(data) == 8
            assert data[7] == crc8_bitwise(data[:7])
            got_name, got = rx.accept(frame_id, data)
            assert got_name == name
            for sig, (_u, _lo, _hi, step) in signals.items():
                assert got[sig] == pytest.approx(values[sig], abs=step / 2 * 1.0001)
        assert rx.counters(name).accepted == 50
    assert rx.total.accepted == 50 * len(MESSAGES)
    assert rx.total.dropped == 0 and rx.total.lost == 0


def test_counter_advances_mod_16(db):
    enc = Encoder(db, "VALVE_COMMAND")
    rx = Receiver(db, ["VALVE_COMMAND"])
    counters = []
    for i in range(40):
        assert enc.counter == i % 16
        data, _ = enc.encode(Command=0.5)
        counters.append(data[6] & 0x0F)
        assert data[6] >> 4 == 0            # reserved upper nibble
        assert rx.accept(0x110, data).values["Counter"] == i % 16
    assert counters == [i % 16 for i in range(40)]
    assert rx.drops == FrameCounters(accepted=40) and rx.total is rx.drops


def test_every_part_counts_the_alive_counter_in_the_dbcs_cycle(db):
    """The DBC's ``Counter`` is 4 bits: the codec wraps it, the log's reader unwraps it
    and the hybrid host places a late feedback within it, all by one cycle (the host's,
    in ``ride_sim`` below the CAN layer, kept equal to it here)."""
    from can_bridge.dbc import COUNTER_BITS, COUNTER_CYCLES
    from ride_sim.hybrid.rig_host import LATE_CYCLES

    for message in db.messages:
        assert message.get_signal_by_name("Counter").length == COUNTER_BITS
    assert COUNTER_CYCLES == 16 == LATE_CYCLES


def test_saturation_is_reported(db):
    enc = Encoder(db, "DAMPER_FORCE")
    data, saturated = enc.encode(Force=20_000.0, Status=0, InputAge=0.1, StrokeUsed=-0.01)
    assert saturated == ("Force", "InputAge")
    values = Receiver(db).decode_values("DAMPER_FORCE", data)
    assert values["Force"] == 16383.5 and values["InputAge"] == pytest.approx(0.0255)
    data, saturated = enc.encode(Force=float("-inf"), Status=255, InputAge=0.0,
                                 StrokeUsed=1.0)
    assert saturated == ("Force", "StrokeUsed")
    values = Receiver(db).decode_values(0x101, data)
    assert values["Force"] == -16384 and values["StrokeUsed"] == pytest.approx(0.32767)
    data, saturated = Encoder(db, "VALVE_COMMAND").encode(Command=1.2)
    assert saturated == ("Command",)
    assert Receiver(db).decode_values(0x110, data)["Command"] == pytest.approx(1.0)
    assert enc.saturated_frames == 2 and enc.frames == 2


def test_encode_rejects_bad_arguments(db):
    enc = Encoder(db, "DAMPER_STATE")
    with pytest.raises(ValueError, match="missing Velocity"):
        enc.encode(Stroke=0.0)
    with pytest.raises(ValueError, match="unknown Force"):
        enc.encode(Stroke=0.0, Velocity=0.0, Force=1.0)
    with pytest.raises(ValueError, match="NaN"):
        enc.encode(Stroke=float("nan"), Velocity=0.0)
    assert enc.counter == 0 and enc.frames == 0
    with pytest.raises(KeyError, match="NOPE"):
        Encoder(db, "NOPE")


def test_receiver_drops_and_counts(db):
    enc = Encoder(db, "DAMPER_STATE")
    rx = Receiver(db, ["DAMPER_STATE", "VALVE_COMMAND"])
    frames = [enc.encode(Stroke=0.001 * i, Velocity=0.1)[0] for i in range(8)]
    assert rx.accept(0x100, frames[0]) is not None                  # counter 0
    bad = bytearray(frames[1])
    bad[7] ^= 0x04                                                  # flipped checksum bit
    assert rx.accept(0x100, bytes(bad)) is None
    bad = bytearray(frames[1])
    bad[0] ^= 0x01                                                  # flipped data bit
    assert rx.accept(0x100, bytes(bad)) is None
    assert rx.accept(0x100, frames[1][:7]) is None                  # DLC 7
    assert rx.accept(0x100, frames[1] + b"\0") is None              # DLC 9
    assert rx.accept(0x100, frames[1]) is not None                  # counter 1
    assert rx.accept(0x100, frames[1]) is None                      # repeated counter
    assert rx.accept(0x101, frames[2]) is None                      # not in the set
    assert rx.accept(0x100, frames[2], is_extended_id=True) is None  # 29-bit id
    assert rx.accept(0x100, frames[5]) is not None                  # 1 -> 5: 3 lost
    c = rx.counters("DAMPER_STATE")
    assert c == FrameCounters(accepted=3, length=2, checksum=2, counter=1, lost=3)
    assert c.dropped == 5
    assert rx.total == FrameCounters(accepted=3, length=2, checksum=2, counter=1, lost=3,
                                     unknown_id=2)
    assert rx.counters("VALVE_COMMAND") == FrameCounters()
    assert rx.last_counter("DAMPER_STATE") == 5
    # wrap-around is an advance of one; after forget_counters any counter is accepted
    for _ in range(8, 16):
        frames.append(enc.encode(Stroke=0.0, Velocity=0.0)[0])
    wrap = enc.encode(Stroke=0.0, Velocity=0.0)[0]                  # counter 0 again
    assert wrap[6] & 0x0F == 0 and frames[15][6] & 0x0F == 15
    assert rx.accept(0x100, frames[15]) is not None                 # 5 -> 15: 9 lost
    assert rx.accept(0x100, wrap) is not None                       # 15 -> 0: none lost
    assert rx.counters("DAMPER_STATE").lost == 12
    rx.forget_counters()
    assert rx.accept(0x100, wrap) is not None
    snapshot = rx.total.copy()
    rx.accept(0x7FF, b"")
    assert snapshot.unknown_id == 2 and rx.total.unknown_id == 3


def test_decode_values_does_not_check(db):
    data, _ = Encoder(db, "DAMPER_STATE").encode(Stroke=0.01, Velocity=-1.0)
    rx = Receiver(db)
    bad = bytearray(data)
    bad[7] ^= 0xFF
    values = rx.decode_values(0x100, bytes(bad))
    assert values["Stroke"] == pytest.approx(0.01) and values["Velocity"] == pytest.approx(-1.0)
    assert rx.total == FrameCounters()
    with pytest.raises(KeyError):
        rx.decode_values(0x555, data)
