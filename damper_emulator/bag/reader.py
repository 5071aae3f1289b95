"""Read rosbag2 bags (any rosbags-readable bag, e.g. ours, closed or killed) without rclpy.

Thin wrapper over ``rosbags.rosbag2.Reader`` that decodes with the Jazzy
typestore and turns every failure into a one-line :class:`BagError`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from rosbags.interfaces import Connection, ConnectionExtRosbag2
from rosbags.rosbag2 import Reader

from damper_emulator.errors import one_line

from .messages import BagError, deserialize, typestore
from .qos import Qos

__all__ = ["Bag", "TopicInfo", "open_bag", "read_messages", "topic_counts"]


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag.

    Attributes
    ----------
    name, msgtype : str
        Topic name and ROS 2 type.
    count : int
        Messages in the MCAP file (from its statistics, or a scan of an unclosed file).
    qos : tuple of Qos
        Offered QoS profiles as recorded (empty if a profile could not be represented).
    type_hash : str
        RIHS01 hash from metadata.yaml (may be empty for other writers' bags).
    """

    name: str
    msgtype: str
    count: int
    qos: tuple[Qos, ...]
    type_hash: str


class Bag:
    """An open bag; use :func:`open_bag`. Context manager; :meth:`close` when done."""

    def __init__(self, path: Path) -> None:
        self.path = path
        if not path.exists():
            raise BagError(f"bag {path}: does not exist")
        if not path.is_dir():
            raise BagError(f"bag {path}: is not a bag directory")
        if not (path / "metadata.yaml").is_file():
            raise BagError(f"bag {path}: no metadata.yaml")
        self._reader: Reader | None = None
        try:
            self._reader = Reader(path)
            self._reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises many kinds
            raise BagError(f"bag {path}: cannot open: {one_line(exc, with_type=True)}") from None
        try:
            self._connections: list[Connection] = list(self._reader.connections)
            counts: dict[str, int] = {}
            start, end = None, None
            storages = getattr(self._reader.storage, "storages", None)
            if storages is not None:
                # counts and times from the MCAP itself: a killed bag's metadata.yaml may lag
                for storage in storages:
                    for conn in storage.connections:
                        counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
                    if storage.metadata.message_count:
                        s, e = storage.metadata.start_time, storage.metadata.end_time - 1
                        start = s if start is None else min(start, s)
                        end = e if end is None else max(end, e)
            else:
                for conn in self._connections:
                    counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
            topics: dict[str, TopicInfo] = {}
            for conn in self._connections:
                ext = conn.ext
                qos: tuple[Qos, ...] = ()
                if isinstance(ext, ConnectionExtRosbag2):
                    try:
                        qos = tuple(Qos.from_rosbags(q) for q in ext.offered_qos_profiles)
                    except BagError:
                        qos = ()
                topics[conn.topic] = TopicInfo(
                    conn.topic, conn.msgtype, counts.get(conn.topic, 0), qos, conn.digest or ""
                )
        except Exception as exc:  # noqa: BLE001
            self.close()
            raise BagError(
                f"bag {path}: cannot read its topics: {one_line(exc, with_type=True)}"
            ) from None
        self.topics: dict[str, TopicInfo] = topics
        self.message_count: int = sum(t.count for t in topics.values())
        #: first and last message timestamp in ns (None for an empty bag)
        self.start_ns: int | None = start
        self.end_ns: int | None = end

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, bytes]]:
        """Yield ``(topic, timestamp_ns, cdr_bytes)`` in timestamp order."""
        conns = self._select(topics)
        reader = self._reader
        if not conns or reader is None:
            return
        try:
            for conn, timestamp, data in reader.messages(connections=conns):
                yield conn.topic, timestamp, bytes(data)
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise BagError(
                f"bag {self.path}: cannot read messages: {one_line(exc, with_type=True)}"
            ) from None

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, int, object]]:
        """Yield ``(topic, timestamp_ns, msg)`` in timestamp order (Jazzy typestore).

        Parameters
        ----------
        topics : iterable of str, optional
            Only these topics (all by default).

        Raises
        ------
        BagError
            Unknown topic or message type, unreadable file, undecodable message.
        """
        conns = self._select(topics)
        known = typestore().types
        for conn in conns:
            if conn.msgtype not in known:
                raise BagError(
                    f"bag {self.path}: topic {conn.topic} has unknown message type {conn.msgtype}"
                )
        if not conns:
            return
        types = {conn.topic: conn.msgtype for conn in conns}
        for topic, timestamp, data in self.raw_messages(t.topic for t in conns):
            try:
                msg = deserialize(data, types[topic])
            except BagError as exc:
                raise BagError(f"bag {self.path}: {topic} at {timestamp} ns: {exc}") from None
            yield topic, timestamp, msg

    def _select(self, topics: Iterable[str] | None) -> list[Connection]:
        if self._reader is None:
            raise BagError(f"bag {self.path}: is closed")
        if topics is None:
            return list(self._connections)
        if isinstance(topics, str):
            topics = [topics]
        wanted = set(topics)
        missing = wanted - {c.topic for c in self._connections}
        if missing:
            raise BagError(f"bag {self.path}: no topic {', '.join(sorted(missing))}")
        return [c for c in self._connections if c.topic in wanted]

    def close(self) -> None:
        """Close the underlying reader (idempotent)."""
        reader, self._reader = self._reader, None
        if reader is not None and reader.is_open:
            reader.close()

    def __enter__(self) -> Bag:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def open_bag(path: str | os.PathLike[str]) -> Bag:
    """Open a bag directory.

    Raises
    ------
    BagError
        Missing directory or metadata.yaml, unreadable metadata or MCAP file.
    """
    return Bag(Path(path))


def read_messages(
    path: str | os.PathLike[str], topics: Iterable[str] | None = None
) -> Iterator[tuple[str, int, object]]:
    """Yield ``(topic, timestamp_ns, msg)`` of a bag in timestamp order (:meth:`Bag.messages`)."""
    with open_bag(path) as bag:
        yield from bag.messages(topics)


def topic_counts(path: str | os.PathLike[str]) -> dict[str, int]:
    """Messages per topic, as stored in the bag's MCAP file."""
    with open_bag(path) as bag:
        return {name: info.count for name, info in bag.topics.items()}
