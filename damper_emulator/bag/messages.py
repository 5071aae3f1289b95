"""ROS 2 Jazzy message definitions and CDR without rclpy.

Everything goes through rosbags' typestore for ROS 2 Jazzy: the ``ros2msg``
definition text that MCAP Schema records carry, the RIHS01 type hash that
rosbag2 stores as ``type_description_hash`` / ``topic_type_hash``, and CDR
serialization of the project's messages.

CDR compatibility with rclpy
----------------------------
For messages whose float64 sequences are not empty, the bytes from
:func:`joint_state` equal what ``rclpy.serialization.serialize_message``
produces, except that rosbags writes the alignment padding as zeros where
rclpy (rmw_fastrtps) leaves whatever was in the buffer. ``serialize_message``
with rmw_fastrtps returns the *estimated* (worst-case) size, so a JointState
with an empty ``velocity`` or ``effort`` comes back with stray trailing bytes
(4 per empty sequence); rosbags' ``deserialize_cdr`` accepts at most 3 and
rejects such a message. What crosses the wire (a ``raw=True`` subscription) is exact. Bags
written from :func:`joint_state` / :func:`float64` are exact; :func:`deserialize`
ignores trailing bytes, as rclpy does.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from damper_emulator.errors import UserError

__all__ = [
    "BagError",
    "deserialize",
    "diagnostic_array",
    "float64",
    "joint_state",
    "msgdef",
    "serialize",
    "type_hash",
    "typestore",
]

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"


class BagError(UserError):
    """A bag could not be written or read; one line naming the bag and the problem."""


@functools.cache
def typestore() -> Typestore:
    """The shared rosbags typestore for ROS 2 Jazzy (built once, about 0.1 s)."""
    return get_typestore(Stores.ROS2_JAZZY)


def _check_type(msgtype: str) -> None:
    if not isinstance(msgtype, str) or msgtype not in typestore().types:
        raise BagError(f"unknown message type {msgtype!r} (not in the ROS 2 Jazzy typestore)")


@functools.cache
def msgdef(msgtype: str) -> str:
    """``ros2msg`` definition text of ``msgtype``, with its dependencies, as rosbag2 stores it.

    Raises
    ------
    BagError
        If the type is not known to the Jazzy typestore.
    """
    _check_type(msgtype)
    text, _ = typestore().generate_msgdef(msgtype, ros_version=2)
    return text


@functools.cache
def type_hash(msgtype: str) -> str:
    """RIHS01 type description hash of ``msgtype`` (``RIHS01_<64 hex digits>``).

    Raises
    ------
    BagError
        If the type is not known to the Jazzy typestore.
    """
    _check_type(msgtype)
    return typestore().hash_rihs01(msgtype)


def serialize(msg: object, msgtype: str) -> bytes:
    """CDR (little endian, with the 4-byte encapsulation header) of a rosbags message object."""
    _check_type(msgtype)
    return bytes(typestore().serialize_cdr(msg, msgtype))


def deserialize(data: bytes | bytearray | memoryview, msgtype: str) -> object:
    """Decode CDR ``data`` into a rosbags message object (dataclass; arrays as numpy).

    Trailing bytes after the message are ignored, as rclpy does (rclpy's
    ``serialize_message`` leaves some after empty float64 sequences, see the
    module docstring).

    Raises
    ------
    BagError
        Unknown type or undecodable data.
    """
    _check_type(msgtype)
    if isinstance(data, bytearray):
        data = bytes(data)
    store = typestore()
    try:
        return store.deserialize_cdr(data, msgtype)
    except SerdeError as exc:
        if "size mismatch" not in str(exc):
            raise BagError(f"cannot decode {msgtype}: {exc}") from None
    # rosbags allows 3 trailing bytes; rmw_fastrtps' estimated size leaves 4 per empty
    # float64 sequence, and rclpy's deserialize_message ignores trailing bytes: so do we.
    definition = store.get_msgdef(msgtype)
    func = definition.deserialize_cdr_le if data[1] else definition.deserialize_cdr_be
    try:
        msg, _ = func(memoryview(data)[4:], 0, definition.cls, store)
    except Exception as exc:  # noqa: BLE001 - any decoder failure is a bad message
        raise BagError(f"cannot decode {msgtype}: {exc}") from None
    return msg


def _time(stamp_ns: int) -> Any:
    if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, (int, np.integer)):
        raise ValueError(f"stamp_ns must be an integer, got {type(stamp_ns).__name__}")
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    if not 0 <= sec < 2**31:
        raise ValueError(f"stamp_ns {stamp_ns} out of range for builtin_interfaces/Time")
    return typestore().types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def _header(stamp_ns: int, frame_id: str) -> Any:
    return typestore().types["std_msgs/msg/Header"](stamp=_time(stamp_ns), frame_id=frame_id)


def _float_array(values: Sequence[float] | np.ndarray, what: str) -> np.ndarray:
    arr = np.ascontiguousarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{what} must be one-dimensional, got shape {arr.shape}")
    return arr


def joint_state(
    stamp_ns: int,
    name: Sequence[str],
    position: Sequence[float] | np.ndarray,
    velocity: Sequence[float] | np.ndarray,
    effort: Sequence[float] | np.ndarray,
    frame_id: str = "",
) -> bytes:
    """CDR of a ``sensor_msgs/msg/JointState`` (about 6 µs).

    Parameters
    ----------
    stamp_ns : int
        ``header.stamp`` in ns since the epoch.
    name : sequence of str
        Joint names.
    position, velocity, effort : sequence of float
        Per-joint values; any may be empty (ROS convention for "not given").
    frame_id : str, optional
        ``header.frame_id``.

    Returns
    -------
    bytes
        Little-endian CDR with encapsulation header.
    """
    msg = typestore().types[JOINT_STATE](
        header=_header(stamp_ns, frame_id),
        name=[str(n) for n in name],
        position=_float_array(position, "position"),
        velocity=_float_array(velocity, "velocity"),
        effort=_float_array(effort, "effort"),
    )
    return bytes(typestore().serialize_cdr(msg, JOINT_STATE))


def float64(value: float) -> bytes:
    """CDR of a ``std_msgs/msg/Float64``."""
    msg = typestore().types[FLOAT64](data=float(value))
    return bytes(typestore().serialize_cdr(msg, FLOAT64))


def diagnostic_array(
    stamp_ns: int,
    statuses: Sequence[tuple[int, str, str, str, Sequence[tuple[str, str]]]],
    frame_id: str = "",
) -> bytes:
    """CDR of a ``diagnostic_msgs/msg/DiagnosticArray``.

    Parameters
    ----------
    stamp_ns : int
        ``header.stamp`` in ns since the epoch.
    statuses : sequence of (level, name, message, hardware_id, [(key, value), ...])
        One ``DiagnosticStatus`` each; level 0 OK, 1 WARN, 2 ERROR, 3 STALE.
    frame_id : str, optional
        ``header.frame_id``.
    """
    types = typestore().types
    status_cls = types["diagnostic_msgs/msg/DiagnosticStatus"]
    kv_cls = types["diagnostic_msgs/msg/KeyValue"]
    status = [
        status_cls(
            level=int(level),
            name=str(name),
            message=str(message),
            hardware_id=str(hardware_id),
            values=[kv_cls(key=str(k), value=str(v)) for k, v in values],
        )
        for level, name, message, hardware_id, values in statuses
    ]
    msg = types[DIAGNOSTIC_ARRAY](header=_header(stamp_ns, frame_id), status=status)
    return bytes(typestore().serialize_cdr(msg, DIAGNOSTIC_ARRAY))
