"""The CAN side: the bridge between the emulator and a CAN dyno or adaptive-damper
controller, and the physical damper in the loop's link and virtual rig.

The CAN layer is pure Python (no rclpy; the bridge's node, :mod:`can_bridge.node`, is the
rclpy shell beside :mod:`can_bridge.core`):

- :mod:`can_bridge.dbc`: the database ``config/damper.dbc`` (cantools), its checks, cycle
  times and bus load;
- :mod:`can_bridge.codec`: :class:`Encoder` / :class:`Receiver`, payloads with the alive
  counter and the CRC-8/SAE-J1850 checksum (:mod:`can_bridge.crc`);
- :mod:`can_bridge.bus`: python-can buses, :class:`ResilientBus`.
"""

from can_bridge.bus import (
                            BusConfig,
                            CanBusError,
                            ResilientBus,
                            open_bus,
                            socketcan_available,
                            socketcan_problem,
)
from can_bridge.codec import Decoded, EncodedFrame, Encoder, FrameCounters, Receiver
from can_bridge.crc import crc8_sae_j1850
from can_bridge.dbc import (
                            DEFAULT_DBC,
                            HYBRID_SIGNALS,
                            REQUIRED_SIGNALS,
                            DbcError,
                            DynoStatus,
                            ForceStatus,
                            bus_load,
                            cycle_time_s,
                            frame_bits,
                            load_database,
                            messages_for,
)

__all__ = [
    "DEFAULT_DBC",
    "HYBRID_SIGNALS",
    "REQUIRED_SIGNALS",
    "BusConfig",
    "CanBusError",
    "DbcError",
    "Decoded",
    "DynoStatus",
    "EncodedFrame",
    "Encoder",
    "ForceStatus",
    "FrameCounters",
    "Receiver",
    "ResilientBus",
    "bus_load",
    "crc8_sae_j1850",
    "cycle_time_s",
    "frame_bits",
    "load_database",
    "messages_for",
    "open_bus",
    "socketcan_available",
    "socketcan_problem",
]
