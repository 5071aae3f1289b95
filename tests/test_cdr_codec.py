"""The precompiled JointState codec of the live nodes' 1 kHz topics
(:class:`damper_emulator.bag.cdr_fast.JointStateCodec` and ``JointStateDecoder``), checked
against rosbags' own CDR serializer and deserializer (an independent implementation)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from damper_emulator.bag import BagError, messages
from damper_emulator.bag.cdr_fast import (
    JointStateCodec,
    JointStateDecoder,
    _parse,
    encode_joint_state,
)

JS = "sensor_msgs/msg/JointState"

names_st = st.lists(st.text(min_size=0, max_size=7), max_size=4)
floats_st = st.floats(allow_nan=True, allow_infinity=True, width=64)
stamp_st = st.integers(min_value=0, max_value=2**31 * 1_000_000_000 - 1)


@st.composite
def messages_st(draw):
    names = draw(names_st)
    counts = tuple(draw(st.integers(0, 4)) for _ in range(3))
    values = draw(st.lists(floats_st, min_size=sum(counts), max_size=sum(counts)))
    frame = draw(st.text(max_size=5))
    return draw(stamp_st), names, counts, values, frame


def _split(values, counts):
    a, b = counts[0], counts[0] + counts[1]
    return values[:a], values[a:b], values[b:]


def _same(a, b) -> bool:
    return len(a) == len(b) and all(x == y or (math.isnan(x) and math.isnan(y))
                                    for x, y in zip(a, b, strict=True))


@given(messages_st())
def test_encoding_equals_rosbags(msg):
    stamp, names, counts, values, frame = msg
    p, v, e = _split(values, counts)
    data = JointStateCodec(names, counts, frame).encode(stamp, values)
    assert data == messages.joint_state(stamp, names, p, v, e, frame_id=frame)
    back = messages.deserialize(data, JS)                      # rosbags' decoder
    assert (back.header.stamp.sec * 10**9 + back.header.stamp.nanosec) == stamp
    assert list(back.name) == names and back.header.frame_id == frame
    assert _same(list(back.position), p) and _same(list(back.effort), e)


@given(st.lists(messages_st(), min_size=1, max_size=6))
def test_a_stream_of_changing_layouts_decodes_as_rosbags_does(stream):
    """One decoder over messages of several layouts: each is decoded right, whether the
    kept layout fits it or not."""
    decoder = JointStateDecoder()
    for stamp, names, counts, values, frame in stream:
        p, v, e = _split(values, counts)
        for _ in range(2):                  # the second time through the kept layout
            got = decoder.decode(messages.joint_state(stamp, names, p, v, e, frame_id=frame)
                                 + b"\x00" * 3)          # trailing bytes are ignored
            assert (got.stamp_ns, got.frame_id, got.name) == (stamp, frame, tuple(names))
            assert _same(got.position, p) and _same(got.velocity, v) and \
                _same(got.effort, e)


def test_padding_is_not_part_of_the_layout_but_names_are():
    """Another serializer may leave garbage in the alignment padding (rclpy does not clear
    it): still this layout.  A name of the same length but other characters is not."""
    codec = JointStateCodec(["damper", "damper/status"], (2, 2, 2))
    data = bytearray(codec.encode(1_000_000_007, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
    _, layout, _, _ = _parse(bytes(data))
    fixed = set()
    for a, b in layout.structural:
        fixed.update(range(a, b))
    for a, n in layout.sequences:
        fixed.update(range(a, a + 8 * n))
    padding = [i for i in range(4, layout.size) if i not in fixed and not 4 <= i < 12]
    assert padding, "this layout has alignment padding"
    for i in padding:
        data[i] = 0xAA
    got = codec.decode(bytes(data))
    assert got is not None and got.effort == (5.0, 6.0)
    other = encode_joint_state(1, ["dampex", "damper/status"], [1, 2], [3, 4], [5, 6])
    assert codec.decode(other) is None
    decoder = JointStateDecoder()
    decoder.decode(bytes(data))
    assert decoder.decode(other).name == ("dampex", "damper/status")


def test_big_endian_and_broken_data():
    store = messages.typestore()
    msg = messages.deserialize(messages.joint_state(5_000_000_001, ["a"], [1.0], [2.0], []),
                               JS)
    big = bytes(store.serialize_cdr(msg, JS, little_endian=False))
    decoder = JointStateDecoder()
    for _ in range(2):
        got = decoder.decode(big)
        assert (got.stamp_ns, got.position, got.velocity) == (5_000_000_001, (1.0,), (2.0,))
    good = messages.joint_state(1, ["damper"], [0.1], [0.2], [0.3])
    decoder.decode(good)
    for bad in (b"", good[:30], good[:-4], b"\x01\x01\x00\x00" + good[4:]):
        with pytest.raises(BagError, match="cannot decode"):
            decoder.decode(bad)


def test_encoding_refuses_what_the_message_cannot_hold():
    codec = JointStateCodec(["damper"], (1, 1, 0))
    with pytest.raises(ValueError, match="2 values expected"):
        codec.encode(0, [1.0])
    with pytest.raises(ValueError, match="out of range"):
        codec.encode(-1, [1.0, 2.0])
    with pytest.raises(ValueError, match="out of range"):
        codec.encode(2**31 * 10**9, [1.0, 2.0])
    assert JointStateCodec([], (0, 0, 0)).encode(3, []) == \
        messages.joint_state(3, [], [], [], [])
    assert np.isnan(JointStateDecoder().decode(
        codec.encode(3, [math.nan, 0.0])).position[0])


def test_rclpy_reads_what_the_codec_writes_and_the_decoder_reads_rclpy():
    """Both ways against rmw_fastrtps' serializer, which leaves the padding uninitialised
    and pads some messages with trailing bytes."""
    pytest.importorskip("rclpy")
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    stamp = 1_700_000_123_456_789_012
    codec = JointStateCodec(["wheel", "body", "road"], (3, 3, 3))
    values = [0.01, -0.02, 0.003, 0.1, 0.2, -0.3, 1500.0, -120.5, 700.25]
    m = deserialize_message(codec.encode(stamp, values), JointState)
    assert divmod(stamp, 10**9) == (m.header.stamp.sec, m.header.stamp.nanosec)
    assert list(m.name) == ["wheel", "body", "road"]
    assert [*m.position, *m.velocity, *m.effort] == values
    decoder = JointStateDecoder()
    for k in range(3):
        m.position = [float(k), 2.0, 3.0]
        m.velocity, m.effort = ([], []) if k == 2 else (m.velocity, m.effort)
        got = decoder.decode(bytes(serialize_message(m)))
        assert got.stamp_ns == stamp and got.position == (float(k), 2.0, 3.0)
        assert got.effort == (() if k == 2 else (1500.0, -120.5, 700.25))
