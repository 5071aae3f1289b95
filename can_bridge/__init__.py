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

from typing import TYPE_CHECKING

if TYPE_CHECKING:
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

#: where each name of the package lives: the package imports none of its modules until a
#: name is asked for (PEP 562), so that a command which only reads the bridge's settings
#: (``can_bridge.settings``) does not import python-can, which imports asammdf and pandas
#: for its MF4 log writer (0.4 s of every ``damper-hil`` command's start)
_HOME = {
    **dict.fromkeys(("BusConfig", "CanBusError", "ResilientBus", "open_bus",
                     "socketcan_available", "socketcan_problem"), "bus"),
    **dict.fromkeys(("Decoded", "EncodedFrame", "Encoder", "FrameCounters", "Receiver"),
                    "codec"),
    "crc8_sae_j1850": "crc",
    **dict.fromkeys(("DEFAULT_DBC", "HYBRID_SIGNALS", "REQUIRED_SIGNALS", "DbcError",
                     "DynoStatus", "ForceStatus", "bus_load", "cycle_time_s", "frame_bits",
                     "load_database", "messages_for"), "dbc"),
}


def __getattr__(name: str) -> object:
    import importlib

    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value
    return value
