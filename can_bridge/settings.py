"""Typed parameters of the ``can_bridge`` node (``damper-hil bridge``).

Defaults live in ``config/bridge.yaml``.  The names are the node's own, without a group
(docs/interfaces.md §5: ``can_interface``, ``can_channel``, ``mode``); every value is
checked by the project's one rule checker (:func:`damper_emulator.schema.check_value`) and
a bad one gives a one-line :class:`~damper_emulator.schema.ParameterError`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from damper_emulator.schema import ParameterError, build_group, check_value, read_yaml, rule

#: Default bridge parameters.
DEFAULT_BRIDGE_FILE = Path(__file__).resolve().parents[1] / "config" / "bridge.yaml"
#: The node's name, and the key of its parameters in ``config/bridge.yaml``.
NODE_NAME = "can_bridge"
MODES = ("dyno", "controller")


@dataclass(frozen=True)
class BridgeParams:
    """How the bridge maps CAN frames (config/damper.dbc) to ROS 2 topics."""

    can_interface: str = rule("text", "python-can interface (socketcan, udp_multicast, "
                                      "virtual, pcan, ...)", "socketcan")
    can_channel: str = rule("text", "python-can channel (vcan0, can0, an ff11:: group, ...)",
                            "vcan0")
    bitrate: int = rule(("int_range", 10000, 8000000), "bus bit rate [bit/s]", 500000)
    mode: str = rule(("choices", MODES),
                     "dyno: DAMPER_STATE → /damper/state, /damper/force → DAMPER_FORCE; "
                     "controller: VALVE_COMMAND → /damper/valve_command, /ride/state → "
                     "VEHICLE_MOTION, /damper/force → DAMPER_FORCE", "dyno")
    model: bool = rule("bool", "dyno: the bridge steps the damper's model itself, in its "
                               "receive thread, and answers each DAMPER_STATE at once with "
                               "the force computed from it (the damper and numerics groups "
                               "of its params files, the emulator group's input checks; "
                               "/damper/state and /damper/force are still published, for "
                               "observation and recording; no emulator node)", False)
    dbc_file: str = rule("text", "CAN database ('' = config/damper.dbc)", "")
    damper_name: str = rule("text", "name[0] of /damper/state (REP-144)", "damper")
    state_timeout_s: float = rule(("range", 0.0, 10.0),
                                  "dyno: no DAMPER_STATE frame this long sets status bit 16 "
                                  "[s]", 0.02)
    force_timeout_s: float = rule(("range", 0.0, 10.0),
                                  "no /damper/force this long: DAMPER_FORCE frames with "
                                  "status bit 32 at the DBC cycle [s]", 0.02)
    command_timeout_s: float = rule(("range", 0.0, 60.0),
                                    "controller: no VALVE_COMMAND frame this long applies "
                                    "fail_safe_command [s]", 0.1)
    fail_safe_command: float = rule(("closed", 0.0, 1.0),
                                    "controller: valve command while the controller is "
                                    "silent [-] (0 comfort .. 1 sport)", 1.0)
    backoff_initial_s: float = rule("positive", "first wait before reopening a failed bus "
                                                "[s]", 0.1)
    backoff_max_s: float = rule("positive", "longest wait between reopen attempts [s]", 5.0)
    diagnostics_period_s: float = rule(("range", 0.0, 60.0), "period of /diagnostics [s]", 1.0)
    sched_fifo: bool = rule("bool", "SCHED_FIFO for the receive thread when permitted", True)
    priority: int = rule(("int_range", 1, 99), "SCHED_FIFO priority of the receive thread",
                         75)
    dds_priority: int = rule(("int_range", 0, 99),
                             "SCHED_FIFO priority of the DDS middleware's threads when "
                             "permitted (0: normal scheduling)", 60)
    emulator_node: str = rule("text", "the managed emulator node the bridge waits for and "
                                      "reports on (its lifecycle state 'active'); until "
                                      "then DAMPER_FORCE frames carry the no-force status "
                                      "('' = do not ask)", "damper_emulator")
    wait_for_emulator_s: float = rule(("range", 0.0, 3600.0),
                                      "say so in one error line when the emulator is not "
                                      "active after this long [s] (the bridge runs on, "
                                      "sending fault frames)", 120.0)
    can_log: str = rule("text", "also log every CAN frame the bridge sends and receives to "
                                "this new file, Vector BLF (.blf) or ASC (.asc), closed "
                                "when the node ends ('' = no log)", "")


def bridge_params_from_mapping(data: Mapping[str, Any] | None,
                               where: str = "<memory>") -> BridgeParams:
    """Build and check :class:`BridgeParams` from a mapping of its parameters."""
    params = build_group(BridgeParams, {} if data is None else data, NODE_NAME, where,
                         check_value)
    if params.model and params.mode != "dyno":
        raise ParameterError(f"{where}: {NODE_NAME}.model is true in mode "
                             f"{params.mode!r}: the bridge steps the model only in mode "
                             "'dyno'")
    if params.backoff_max_s < params.backoff_initial_s:
        raise ParameterError(f"{where}: {NODE_NAME}.backoff_max_s ({params.backoff_max_s:g}) "
                             f"must be >= backoff_initial_s ({params.backoff_initial_s:g})")
    return params


def default_bridge_mapping() -> dict[str, Any]:
    """The parameters of ``config/bridge.yaml`` (the defaults)."""
    where = str(DEFAULT_BRIDGE_FILE)
    doc = read_yaml(DEFAULT_BRIDGE_FILE)
    try:
        return dict(doc[NODE_NAME]["ros__parameters"])
    except (KeyError, TypeError):
        raise ParameterError(f"{where}: expected '{NODE_NAME}: ros__parameters: ...'") from None


def field_names() -> tuple[str, ...]:
    return tuple(f.name for f in fields(BridgeParams))
