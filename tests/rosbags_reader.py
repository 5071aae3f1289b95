"""A bag read back by rosbags alone, the independent reader (tests/test_nodes.py,
tests/test_demo_run.py)."""

from __future__ import annotations

from pathlib import Path

from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def read_bag(path: Path) -> dict[str, list]:
    """Every message of a bag, decoded by rosbags alone: ``{topic: [(stamp, message)]}``."""
    out: dict[str, list] = {}
    with Reader(path) as reader:
        for conn, t, data in reader.messages():
            out.setdefault(conn.topic, []).append(
                (t, TYPESTORE.deserialize_cdr(data, conn.msgtype)))
    return out
