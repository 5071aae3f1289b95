"""Typed parameters of the ``damper_emulator`` node (group ``emulator``).

Defaults live in ``config/emulator.yaml``; a node started with ``--ros-args --params-file
FILE`` takes them from there.  Every value is checked with the project's one rule checker
(:func:`damper_emulator.schema.check_value`); a bad value gives a one-line
:class:`~damper_emulator.schema.ParameterError`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from damper_emulator.realtime.rt import RealtimeRequest
from damper_emulator.schema import (
    ParameterError,
    build_group,
    check_value,
    node_parameters,
    read_yaml,
    rule,
)

#: Default emulator node parameters.
DEFAULT_EMULATOR_FILE = Path(__file__).resolve().parents[2] / "config" / "emulator.yaml"

TRIGGERS = ("timer", "input")
INPUT_MODES = ("hold", "extrapolate")
FAULT_MODES = ("hold", "zero", "passive")


@dataclass(frozen=True)
class EmulatorParams:
    """How the emulator node turns ``/damper/state`` into ``/damper/force``."""

    name: str = rule("text", "the damper's name, name[0] of the messages (REP-144)", "damper")
    rate_hz: float = rule(("range", 0.0, 20000.0), "output rate of the fixed-rate loop [Hz]",
                          1000.0)
    trigger: str = rule(("choices", TRIGGERS),
                        "timer: fixed-rate loop at rate_hz (hardware in the loop); input: one "
                        "force per input sample, the model advanced by the difference of the "
                        "samples' stamps (lockstep simulation, replay)", "timer")
    phase_lock_us: float = rule("non-negative",
                                "timer trigger: move the loop's ticks, a little per tick, to "
                                "follow each input's arrival by this lag, shorter than a "
                                "period (the rate stays rate_hz, or follows an input clock up to "
                                "about 1 % off; 0: ticks on the loop's own phase) [µs]", 200.0)
    input_mode: str = rule(("choices", INPUT_MODES),
                           "between input samples: hold the stroke, or extrapolate it with "
                           "the sample's velocity (at most max_extrapolation_s)", "hold",
                           runtime=True)
    max_extrapolation_s: float = rule("non-negative",
                                      "longest extrapolation of the stroke [s]", 5e-3, runtime=True)
    input_timeout_s: float = rule(("range", 0.0, 10.0),
                                  "input older than this is a fault (fault_mode applies) [s]",
                                  0.02, runtime=True)
    fault_mode: str = rule(("choices", FAULT_MODES),
                           "output while the input is stale: hold the last force, zero, or "
                           "passive (static gas force + passive_rate_ns_m × last velocity)",
                           "hold", runtime=True)
    passive_rate_ns_m: float = rule("non-negative",
                                    "linear rate of the passive fault output, damper side "
                                    "[N s/m]", 5899.5, runtime=True)
    max_velocity_m_s: float = rule("positive",
                                   "input with a larger |velocity| is rejected [m/s]", 10.0,
                                   runtime=True)
    stroke_tolerance_m: float = rule("non-negative",
                                     "input stroke this far beyond the damper's travel is "
                                     "rejected [m] (within it, the model clamps and flags)",
                                     5e-3, runtime=True)
    valve_command: float = rule(("closed", 0.0, 1.0),
                                "initial valve command [-], 0 softest .. 1 firmest ('sport')",
                                1.0)
    sched_fifo: bool = rule("bool", "run the loop thread under SCHED_FIFO when permitted",
                            True)
    priority: int = rule(("int_range", 1, 99), "SCHED_FIFO priority of the loop thread", 80)
    lock_memory: bool = rule("bool", "mlockall the process when permitted", True)
    dds_priority: int = rule(("int_range", 0, 99),
                             "SCHED_FIFO priority of the DDS middleware's threads (receive, "
                             "events) when permitted; below the loop's, so that input "
                             "arrives on a busy machine (0: normal scheduling)", 60)
    cpu_affinity: int = rule(("int_range", -1, 1023),
                             "pin the loop thread to this CPU (-1: no pinning)", -1)
    cpu_dma_latency_us: int = rule(("int_range", -1, 100000),
                                   "while the loop runs, cap the CPUs' wake-up latency [µs] "
                                   "through /dev/cpu_dma_latency when permitted (0: idle CPUs "
                                   "poll; -1: no request)", 0)
    diagnostics_period_s: float = rule(("range", 0.0, 60.0),
                                       "period of /diagnostics [s]", 1.0, runtime=True)
    stats_window_s: float = rule(("range", 0.0, 3600.0),
                                 "loop periods kept for the statistics [s]", 120.0)
    stats_file: str = rule("text", "write the loop periods and counters here (.npz) at "
                                   "shutdown ('' = do not)", "")
    live_port: int = rule(("int_range", 0, 65535),
                          "serve the live view (Foxglove WebSocket on 127.0.0.1, channels "
                          "/live/damper and /live/loop) on this port, fed from the executor "
                          "thread, never the loop; needs foxglove-sdk (0 = off)", 0)

    def __post_init__(self) -> None:
        period_us = 1e6 / self.rate_hz if self.rate_hz > 0 else float("inf")
        if self.trigger == "timer" and self.phase_lock_us >= period_us:
            raise ParameterError(
                f"emulator.phase_lock_us = {self.phase_lock_us:g} must be shorter than the "
                f"loop's period ({period_us:g} µs at rate_hz {self.rate_hz:g}); 0 turns the "
                "lock off")

    def realtime_request(self) -> RealtimeRequest:
        return RealtimeRequest(sched_fifo=self.sched_fifo, priority=self.priority,
                               lock_memory=self.lock_memory, cpu=self.cpu_affinity,
                               cpu_dma_latency_us=self.cpu_dma_latency_us)


#: Parameters that may change while the node runs (``rule(..., runtime=True)`` in the
#: schema); the others need a restart.
RUNTIME_PARAMETERS = tuple(f.name for f in fields(EmulatorParams) if f.metadata["runtime"])


def emulator_params_from_mapping(data: Mapping[str, Any] | None,
                                 where: str = "<memory>") -> EmulatorParams:
    """Build and check :class:`EmulatorParams` from the ``emulator`` group's mapping."""
    return build_group(EmulatorParams, {} if data is None else data, "emulator", where,
                       check_value)


def default_emulator_mapping() -> dict[str, Any]:
    """The ``emulator`` group of ``config/emulator.yaml`` (the defaults)."""
    where = str(DEFAULT_EMULATOR_FILE)
    return dict(node_parameters(read_yaml(DEFAULT_EMULATOR_FILE), where, "emulator")["emulator"])


def field_names() -> tuple[str, ...]:
    return tuple(f.name for f in fields(EmulatorParams))
