"""The ``/damper/force`` layout (docs/interfaces.md §5), written and read in one place:
what :mod:`damper_emulator.force_message` writes, rosbags' own CDR decoder reads back with
the documented meaning, and the column readers recover from a mixed batch."""

from __future__ import annotations

import math

import numpy as np
import pytest

from damper_emulator import force_message as fm
from damper_emulator.bag import cdr_fast, messages
from damper_emulator.realtime.core import Status

JOINT_STATE = "sensor_msgs/msg/JointState"


def _cdr(damper: str, values: tuple[float, ...], stamp_ns: int = 1) -> bytes:
    """As the emulator node publishes it (ros.common.JointStateOut)."""
    return cdr_fast.JointStateCodec(fm.names(damper), fm.COUNTS).encode(stamp_ns, values)


def test_one_output_as_documented_decoded_by_rosbags():
    status = Status.TIMEOUT | Status.REJECTED
    values = fm.values(-812.5, int(status), 0.0123, -0.4, 0.0021)
    msg = messages.deserialize(_cdr("front_left", values), JOINT_STATE)  # rosbags' decoder
    assert list(msg.name) == ["front_left", "front_left/status"]
    assert msg.effort[0] == -812.5 and Status(int(msg.effort[1])) == status
    assert msg.position[0] == 0.0123 and msg.position[1] == 0.0021
    assert msg.velocity[0] == -0.4 and msg.velocity[1] == 0.0
    assert fm.status_of(msg.effort) == int(status)
    assert fm.input_age_of(msg.position) == 0.0021


def test_no_input_writes_zero_motion_and_no_age():
    msg = messages.deserialize(_cdr("damper", fm.values(
        250.0, int(Status.NO_INPUT), math.nan, math.nan, math.nan)), JOINT_STATE)
    assert list(msg.position) == [0.0, fm.NO_AGE] and list(msg.velocity) == [0.0, 0.0]
    assert Status(fm.status_of(msg.effort)).fault


def test_a_contract_only_message_reads_as_ok_without_age():
    assert fm.status_of([120.0]) == 0
    assert fm.status_of([120.0, math.nan]) == 0
    assert fm.input_age_of([0.01]) == fm.NO_AGE
    assert fm.input_age_of([0.01, math.nan]) == fm.NO_AGE


@pytest.mark.slow
def test_columns_round_trip_through_cdr_and_tolerate_contract_only_messages():
    rng = np.random.default_rng(5)
    n = 7
    force = rng.normal(0.0, 1000.0, n)
    status = rng.integers(0, 16, n)
    stroke, vel = rng.normal(0.0, 0.02, n), rng.normal(0.0, 0.5, n)
    age = rng.uniform(0.0, 0.003, n)
    pos, velo, eff = fm.columns(force, status, stroke, vel, age)
    rows = cdr_fast.rows_to_bytes(cdr_fast.encode_joint_states(
        np.arange(n), fm.names("damper"), pos, velo, eff))
    # and one message of a publisher that fills only the contract's entry
    rows.append(messages.joint_state(99, ["damper"], [0.01], [0.2], [55.0]))
    offsets = np.cumsum([0] + [len(r) for r in rows[:-1]])
    lengths = np.array([len(r) for r in rows])
    js = cdr_fast.decode_joint_states(b"".join(rows), offsets, lengths)
    np.testing.assert_array_equal(fm.status_column(js), np.append(status, 0))
    np.testing.assert_array_equal(fm.age_column(js), np.append(age, fm.NO_AGE))
    np.testing.assert_array_equal(js.effort[:n, 0], force)
