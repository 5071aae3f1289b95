"""The offered QoS profile of a recorded topic and the YAML rosbag2 writes it in.

:class:`Qos` is rosbag2's ``offered_qos_profiles`` entry (version 9 names), converted to
and from ``rosbags``' own type; :class:`Topic` is the handle a
:class:`~damper_emulator.bag.writer.BagWriter` returns for a recorded topic.
"""

from __future__ import annotations

from dataclasses import dataclass

import yaml
from rosbags.interfaces import Qos as RosbagsQos
from rosbags.interfaces import QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2.metadata import dump_qos_v9

from .messages import BagError

__all__ = ["INFINITE_NS", "Qos", "Topic", "dump_yaml", "qos_yaml"]

#: ROS' "infinite" duration [ns]
INFINITE_NS = 2**63 - 1

_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)

_RELIABILITY = ("system_default", "reliable", "best_effort", "best_available")
_DURABILITY = ("system_default", "transient_local", "volatile", "best_available")
_HISTORY = ("system_default", "keep_last", "keep_all")
_LIVELINESS = ("system_default", "automatic", "manual_by_node", "manual_by_topic", "best_available")


def _qos_time(ns: int) -> QosTime:
    sec, nsec = divmod(ns, 1_000_000_000)
    return QosTime(sec, nsec)


@dataclass(frozen=True)
class Qos:
    """Offered QoS profile of a recorded topic (rosbag2 ``offered_qos_profiles``).

    Parameters
    ----------
    reliability : str
        ``"reliable"``, ``"best_effort"``, ``"system_default"`` or ``"best_available"``.
    durability : str
        ``"volatile"``, ``"transient_local"``, ``"system_default"`` or ``"best_available"``.
    history : str
        ``"keep_last"``, ``"keep_all"`` or ``"system_default"``.
    depth : int
        History depth.
    deadline_ns, lifespan_ns, liveliness_lease_duration_ns : int
        Durations in ns; the default ``2**63 - 1`` is ROS' "infinite".
    liveliness : str
        ``"automatic"``, ``"manual_by_topic"``, ``"manual_by_node"`` (deprecated in ROS 2),
        ``"system_default"`` or ``"best_available"``.
    avoid_ros_namespace_conventions : bool
        As in rclpy.
    """

    reliability: str = "reliable"
    durability: str = "volatile"
    history: str = "keep_last"
    depth: int = 10
    deadline_ns: int = INFINITE_NS
    lifespan_ns: int = INFINITE_NS
    liveliness: str = "automatic"
    liveliness_lease_duration_ns: int = INFINITE_NS
    avoid_ros_namespace_conventions: bool = False

    def __post_init__(self) -> None:
        for field, allowed in (
            ("reliability", _RELIABILITY),
            ("durability", _DURABILITY),
            ("history", _HISTORY),
            ("liveliness", _LIVELINESS),
        ):
            if getattr(self, field) not in allowed:
                raise BagError(
                    f"QoS {field} must be one of {', '.join(allowed)}, got {getattr(self, field)!r}"
                )
        for field in ("depth", "deadline_ns", "lifespan_ns", "liveliness_lease_duration_ns"):
            value = getattr(self, field)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**63:
                raise BagError(f"QoS {field} must be an integer in [0, 2**63), got {value!r}")
        if not isinstance(self.avoid_ros_namespace_conventions, bool):
            raise BagError("QoS avoid_ros_namespace_conventions must be a bool")

    def to_rosbags(self) -> RosbagsQos:
        """The same profile as a ``rosbags.interfaces.Qos``."""
        return RosbagsQos(
            history=QosHistory[self.history.upper()],
            depth=self.depth,
            reliability=QosReliability[self.reliability.upper()],
            durability=QosDurability[self.durability.upper()],
            deadline=_qos_time(self.deadline_ns),
            lifespan=_qos_time(self.lifespan_ns),
            liveliness=QosLiveliness[self.liveliness.upper()],
            liveliness_lease_duration=_qos_time(self.liveliness_lease_duration_ns),
            avoid_ros_namespace_conventions=self.avoid_ros_namespace_conventions,
        )

    @classmethod
    def from_rosbags(cls, qos: RosbagsQos) -> Qos:
        """Convert a ``rosbags.interfaces.Qos`` (as parsed from a bag).

        Raises
        ------
        BagError
            For enum values this class does not represent (``unknown``).
        """

        def ns(t: QosTime) -> int:
            return int(t.sec) * 1_000_000_000 + int(t.nsec)

        return cls(
            reliability=qos.reliability.name.lower(),
            durability=qos.durability.name.lower(),
            history=qos.history.name.lower(),
            depth=int(qos.depth),
            deadline_ns=ns(qos.deadline),
            lifespan_ns=ns(qos.lifespan),
            liveliness=qos.liveliness.name.lower(),
            liveliness_lease_duration_ns=ns(qos.liveliness_lease_duration),
            avoid_ros_namespace_conventions=bool(qos.avoid_ros_namespace_conventions),
        )


@dataclass(frozen=True, eq=False)
class Topic:
    """Handle returned by :meth:`BagWriter.add_topic`; pass it to :meth:`BagWriter.write`."""

    name: str
    msgtype: str
    qos: Qos
    channel_id: int


def dump_yaml(data: object) -> str:
    """Block-style YAML, keys in insertion order (as rosbag2's yaml-cpp writes them)."""
    return str(yaml.dump(data, Dumper=_DUMPER, default_flow_style=False, sort_keys=False))


def qos_yaml(qos: Qos) -> str:
    """``offered_qos_profiles`` string for an MCAP Channel (version 9 names)."""
    return dump_yaml(dump_qos_v9([qos.to_rosbags()])).strip()
