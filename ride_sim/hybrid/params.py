"""Parameter schemas of the damper-in-the-loop rig (one per group, :func:`rule` fields).

``actuator`` (:class:`ActuatorParams`): the dyno's transfer system from the stroke demand
to the stroke it achieves; ``virtual_rig`` (:class:`RigParams`): what the virtual dyno adds
(sensor noise, its own travel); ``safety`` (:class:`SafetyParams`): what the host never
lets the rig do.  Every value is checked on loading (:func:`build`); a bad one is a
one-line :class:`~damper_emulator.schema.ParameterError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from damper_emulator.schema import ParameterError, build_group, node_parameters, read_yaml
from damper_emulator.schema import check_value as _check
from damper_emulator.schema import rule as _rule

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

_G = TypeVar("_G", bound="DataclassInstance")


@dataclass(frozen=True)
class ActuatorParams:
    """The transfer system: the demand reaches the servo after a transport delay, and the
    servo follows it as a second-order system,

        G(s) = g ω² e^(−s τ) / (s² + 2 ζ ω s + ω²),   ω = 2π f_servo.
    """

    delay_s: float = _rule(("closed", 0.0, 0.2), "transport delay τ of the demand (CAN, "
                                                  "the rig controller's cycle) [s]", 4e-3)
    bandwidth_hz: float = _rule(("range", 0.0, 1000.0), "servo natural frequency f_servo "
                                                         "[Hz]", 40.0)
    damping: float = _rule(("range", 0.0, 10.0), "servo damping ratio ζ [-]", 0.7)
    gain: float = _rule(("range", 0.0, 10.0), "static gain g, achieved / demanded "
                                              "stroke [-]", 1.0)


@dataclass(frozen=True)
class RigParams:
    """The virtual dyno (``damper-hil virtual-rig``) besides its actuator."""

    rate_hz: float = _rule(("range", 0.0, 20000.0), "control and feedback rate [Hz]", 1000.0)
    force_noise_n: float = _rule("non-negative", "load-cell noise, standard deviation [N]",
                                 2.0)
    stroke_noise_m: float = _rule("non-negative", "displacement-sensor noise, standard "
                                                  "deviation [m]", 5e-6)
    travel_m: float = _rule("positive", "the actuator's end stops, ± from the static "
                                        "position [m]", 0.08)
    hold_after_s: float = _rule("positive", "no valid DYNO_COMMAND for this long: hold "
                                            "the position and clear Status.enabled [s]",
                                0.05)
    seed: int = _rule(("int_range", 0, 2 ** 31 - 1), "noise generator seed", 0)


@dataclass(frozen=True)
class SafetyParams:
    """What the host never lets the rig do (:mod:`ride_sim.hybrid.safety`).

    A demand is clamped into the stroke limits and rate-limited to the velocity limit; a
    measured stroke, velocity or force beyond its limit, feedback older than
    ``watchdog_s``, or a loop going unstable stops the run in order.
    """

    stroke_limit_m: float = _rule("positive", "largest stroke demanded or measured, ± from "
                                              "the static position [m]", 0.06)
    velocity_limit_m_s: float = _rule("positive", "largest stroke velocity demanded or "
                                                  "measured [m/s]", 1.5)
    force_limit_n: float = _rule("positive", "largest force measured [N]", 8000.0)
    watchdog_s: float = _rule(("range", 0.0, 1.0), "clear Enable when the last valid "
                                                    "DYNO_FEEDBACK is this old [s]", 0.05)
    velocity_span_s: float = _rule(("range", 0.0, 1.0), "the measured velocity is the "
                                                         "stroke's change over this time [s]",
                                   0.005)
    window_s: float = _rule(("range", 0.0, 10.0), "instability detector: window of the "
                                                   "tracking error's r.m.s. [s]", 0.1)
    reference_window_s: float = _rule(("range", 0.0, 60.0),
                                      "instability detector: the reference stroke's r.m.s. "
                                      "is taken over this trailing time [s]", 1.0)
    growth_windows: int = _rule(("int_range", 1, 100), "instability detector: consecutive "
                                                       "windows of growing error that stop "
                                                       "the run", 2)
    growth_ratio: float = _rule(("range", 1.0, 100.0), "instability detector: each window's "
                                                        "error at least this many times the "
                                                        "last's [-]", 1.5)
    error_ratio: float = _rule("positive", "instability detector: the error's r.m.s. over "
                                           "the reference stroke's (+ error_floor_m) from "
                                           "which growth stops the run [-]", 2.0)
    error_floor_m: float = _rule("positive", "instability detector: added to the reference "
                                             "stroke's r.m.s. (a still road is no "
                                             "instability) [m]", 5e-4)


ROAD_CLASSES = ("A", "B", "C", "D", "E")


@dataclass(frozen=True)
class HybridRunParams:
    """One run of ``damper-hil hybrid`` (:class:`ride_sim.hybrid.host.HybridHost`)."""

    duration_s: float = _rule(("range", 0.0, 3600.0), "evaluated ride [s]", 20.0)
    speed_m_s: float = _rule(("range", 0.0, 100.0), "vehicle speed [m/s]", 20.0)
    road_class: str = _rule(("choices", ROAD_CLASSES), "ISO 8608 road class (its mean "
                                                       "roughness)", "C")
    seed: int = _rule(("int_range", 0, 2 ** 31 - 1), "random-road seed", 0)
    ramp_s: float = _rule(("range", 0.0, 60.0), "the road ramps in over this time before "
                                                 "the evaluated ride, and out after it [s]",
                          1.0)
    settle_s: float = _rule(("range", 0.0, 60.0), "hold at the static position before the "
                                                   "identification; the force's mean over "
                                                   "its second half is the static force [s]",
                            0.5)
    approach_speed_m_s: float = _rule("positive", "speed of the moves to and from the static "
                                                  "position [m/s]", 0.02)
    connect_timeout_s: float = _rule(("range", 0.0, 600.0), "no DYNO_FEEDBACK for this long "
                                                             "at the start: no dyno [s]", 10.0)
    max_fit_nrms: float = _rule("positive", "the identification fits the rig's answer at "
                                            "least this well (r.m.s. error / r.m.s. "
                                            "stroke), or the run stops [-]", 0.2)
    restarts: int = _rule(("int_range", 0, 10), "a stop of the watchdog or of a stall of "
                                                "the host before the run proper (settle, "
                                                "identification, fit) clears Enable for "
                                                "watchdog_s and starts the run again from "
                                                "connect, up to this many times (in the "
                                                "run proper a stop is final)", 2)
    poll_before_s: float = _rule(("closed", 0.0, 0.01),
                                 "with its loop pinned to a CPU (--cpu), the host polls the "
                                 "bus, without sleeping, from this long before the next "
                                 "DYNO_FEEDBACK is due: the wake-up's latency leaves the "
                                 "response time, for that CPU busy that long each cycle (0, "
                                 "or unpinned: it sleeps until the frame comes) [s]", 4e-4)


@dataclass(frozen=True)
class LearnParams:
    """How the twin learns the specimen: before the ride (``hybrid --learn``) and during it.

    Before: a quasi-static test and a chirp run on the rig under the safety layer, and the
    paper's parameters are identified from them into the twin
    (:mod:`ride_sim.hybrid.learn`).  During: a bounded recursive least-squares correction
    of the twin's force map (:mod:`ride_sim.hybrid.online`)."""

    quasi_static_velocity_m_s: float = _rule(("range", 0.0, 0.5), "the quasi-static "
                                                                 "test's constant stroke "
                                                                 "velocity [m/s]", 0.02)
    quasi_static_amplitude_m: float = _rule(("range", 0.0, 0.2), "the quasi-static test's "
                                                                "amplitude [m]", 0.02)
    chirp_s: float = _rule(("range", 0.0, 600.0), "the chirp's duration [s]", 12.0)
    chirp_band_hz: tuple[float, float] = _rule("band", "the chirp's start and end "
                                                       "frequencies [Hz]", (0.5, 12.0))
    chirp_start_velocity_m_s: float = _rule(("range", 0.0, 20.0), "the chirp's velocity "
                                                                 "amplitude at its start "
                                                                 "[m/s]", 0.05)
    chirp_end_velocity_m_s: float = _rule(("range", 0.0, 20.0), "the chirp's velocity "
                                                               "amplitude at its end [m/s]",
                                          1.0)
    attempts: int = _rule(("int_range", 1, 10), "runs of each test at most: a test the "
                                                "watchdog or a stall of the host stopped "
                                                "runs again (a limit the specimen reached "
                                                "stops the learning)", 3)
    online: bool = _rule("bool", "the twin keeps learning during the ride (a bounded "
                                 "correction of its force map)", True)
    online_window_s: float = _rule(("range", 0.05, 60.0), "the online correction's memory "
                                                         "(its forgetting) [s]", 2.0)
    online_gain_bound: float = _rule(("range", 0.0, 0.9), "the online correction's valve "
                                                         "gains stay within 1 ± this [-]",
                                     0.5)


def build(cls: type[_G], data: Any, prefix: str, where: str = "<memory>") -> _G:
    """The group ``cls`` from the mapping ``data`` (missing keys take their defaults).

    Raises
    ------
    damper_emulator.schema.ParameterError
        One line naming ``prefix.key``, the rule and ``where``.
    """
    return build_group(cls, {} if data is None else data, prefix, where, _check)


COMPENSATION_MODES = ("model", "none")


@dataclass(frozen=True)
class CompensatorParams:
    """How the host compensates the transfer system (:mod:`ride_sim.hybrid.compensator`)
    and follows it (:class:`ride_sim.hybrid.transfer.TransferTracker`)."""

    mode: str = _rule(("choices", COMPENSATION_MODES),
                      "model: the servo's inverse on the car's stroke predicted by the car's "
                      "and the damper's models; none: demand the car's stroke as it is",
                      "model")
    force_correction_hz: float = _rule(("range", 0.0, 500.0),
                                       "band of the measured force's correction of the "
                                       "twin's force in the prediction [Hz]", 10.0)
    adapt: bool = _rule("bool", "follow the rig's delay and gain during the ride", True)
    adapt_window_s: float = _rule(("range", 0.05, 10.0), "data each update of the delay and "
                                                          "gain uses [s]", 1.0)
    adapt_period_s: float = _rule(("range", 0.0, 10.0), "time between updates [s]", 0.1)
    max_delay_s: float = _rule(("range", 0.0, 0.5), "longest rig delay identified or "
                                                     "followed [s]", 0.05)
    identify_s: float = _rule(("range", 0.5, 60.0), "transfer-system identification before "
                                                     "the ride [s]", 3.0)
    identify_amplitude_m: float = _rule(("range", 0.0, 0.01), "peak stroke of the "
                                                               "identification [m]", 1e-3)
    identify_band_hz: tuple[float, float] = _rule("band", "band of the identification "
                                                          "signal [Hz]", (0.5, 30.0))
    stall_guard_s: float = _rule(("range", 0.0, 1.0), "a cycle that a stall disturbed "
                                                       "(its feedback or its command 3 cycles "
                                                       "late or more) is left out of the "
                                                       "identification's fit and of the "
                                                       "tracking outside stalls, with this "
                                                       "long after it: the rig's delay and "
                                                       "its servo's settling [s]", 0.02)
    identify_attempts: int = _rule(("int_range", 1, 10), "the identification runs again, up "
                                                          "to this many times in all, while "
                                                          "its fit misses max_fit_nrms or "
                                                          "stalls leave too little of it", 3)


@dataclass(frozen=True)
class HybridConfig:
    """Every group of a damper-in-the-loop parameter file (``config/hybrid.yaml``)."""

    hybrid: HybridRunParams = field(default_factory=HybridRunParams)
    actuator: ActuatorParams = field(default_factory=ActuatorParams)
    virtual_rig: RigParams = field(default_factory=RigParams)
    safety: SafetyParams = field(default_factory=SafetyParams)
    compensator: CompensatorParams = field(default_factory=CompensatorParams)
    learn: LearnParams = field(default_factory=LearnParams)


#: the groups of :class:`HybridConfig`, by key
GROUPS: dict[str, type] = {"hybrid": HybridRunParams, "actuator": ActuatorParams,
                           "virtual_rig": RigParams, "safety": SafetyParams,
                           "compensator": CompensatorParams, "learn": LearnParams}
#: the default parameter file
DEFAULT_HYBRID_FILE = Path(__file__).resolve().parents[2] / "config" / "hybrid.yaml"


def load_hybrid_config(path: str | Path | None = None) -> HybridConfig:
    """The groups of a ROS 2 params file (or a bare mapping of them); a group or key it
    lacks takes its default.

    Raises
    ------
    ParameterError
        One line: an unknown group or key, or a value outside its rule.
    """
    path = Path(path) if path is not None else DEFAULT_HYBRID_FILE
    where = str(path)
    doc = read_yaml(path)
    params = node_parameters(doc, where, group="hybrid")
    unknown = sorted(set(params) - set(GROUPS), key=str)
    if unknown:
        raise ParameterError(f"{where}: unknown parameter group {unknown[0]!r} (one of "
                             f"{', '.join(GROUPS)})")
    return HybridConfig(**{key: build(cls, params.get(key), key, where)
                           for key, cls in GROUPS.items()})
