"""Typed quarter-car and simulation parameters, loaded from a ROS 2 params file.

The file (default ``config/quarter_car.yaml``) has the layout of ``config/sport.yaml``::

    /**:
      ros__parameters:
        quarter_car: {sprung_mass_kg: ..., ...}
        simulation: {step_s: ..., ...}
        road: {roughness: ..., ...}          # optional: the ride studies' roads

``road`` (:class:`RoadParams`) defines the random road and the pothole of the ride studies
(:mod:`ride_sim.study`, ``docs/ride_study.md``); every key has a default.  The virtual
damper tuning's settings and design bounds (:class:`TuneSettings`, :class:`TuneBounds`;
:mod:`ride_sim.tuning`) are schemas here too.

(or the bare mapping inside ``ros__parameters``).  The quarter car is the two-mass model of
Simms & Crolla eq 38 (``docs/model.md`` §5); its values are the paper's front corner
(Figure 8).  Every value is checked; a bad file raises
:class:`damper_emulator.schema.ParameterError` whose message is one line naming the file,
the key and the rule that was broken.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from damper_emulator.dyno.protocols import FourteenSpeed
from damper_emulator.schema import build_group, node_parameters, read_yaml
from damper_emulator.schema import check_value as _check
from damper_emulator.schema import rule as _rule
from ride_sim.road_synthesis import AMPLITUDE_METHODS

#: Default parameter file: the paper's front quarter car.
DEFAULT_QUARTER_CAR_FILE = Path(__file__).resolve().parent.parent / "config" / "quarter_car.yaml"

#: Damper kinds understood by :func:`ride_sim.dampers.make_damper`.
DAMPER_KINDS = ("linear", "14speed", "incompressible", "compressible", "nonlinear")
#: How the synthesised band follows the speed in a speed sweep (:class:`RoadParams`).
BAND_SCALINGS = ("spatial", "temporal")


@dataclass(frozen=True)
class QuarterCarParams:
    """Two-mass quarter car, eq 38 (docs/model.md §5), SI units.

    ``spring_rate_n_m`` and ``linear_damping_ns_m`` are *wheel* rates (``K_s``, ``C_s``).
    The damper acts through ``motion_ratio`` = wheel travel / damper travel: damper
    velocity = suspension velocity / MR, wheel force = damper force / MR, so a damper-side
    linear rate ``c`` is ``c / MR²`` at the wheel.
    """

    sprung_mass_kg: float = _rule("positive", "sprung (body) mass M_b [kg], eq 38")
    unsprung_mass_kg: float = _rule("positive", "unsprung (wheel) mass M_w [kg], eq 38")
    tyre_stiffness_n_m: float = _rule("positive", "tyre stiffness K_t [N/m], eq 38")
    spring_rate_n_m: float = _rule("positive", "suspension spring wheel rate K_s [N/m], eq 38")
    linear_damping_ns_m: float = _rule(
        "non-negative", "linear damper rate at the wheel C_s [N s/m], eq 38")
    motion_ratio: float = _rule("positive", "wheel travel / damper travel [-]")
    tyre_damping_ns_m: float = _rule(
        "non-negative", "tyre damping C_t [N s/m] (0 in eq 38)", 0.0)

    @property
    def damper_linear_rate_ns_m(self) -> float:
        """``C_s`` referred to the damper: ``C_s · MR²`` [N s/m]."""
        return self.linear_damping_ns_m * self.motion_ratio ** 2


@dataclass(frozen=True)
class SimulationParams:
    """Time stepping of the ride simulation."""

    step_s: float = _rule(("range", 0.0, 0.01),
                          "vehicle/damper sample period dt [s]; the damper force is held "
                          "over each step", 1e-3)
    damper: str = _rule(("choices", DAMPER_KINDS), "damper representation", "compressible")
    fourteen_speed_points: int = _rule(("int_range", 2, 1000),
                                       "points of the N-speed test table",
                                       FourteenSpeed.points)


@dataclass(frozen=True)
class RoadParams:
    """Roads of the ride studies (:mod:`ride_sim.study`; ``docs/ride_study.md``).

    The random road is eq 39, ``S(n) = G n^(-p)``, synthesised over ``band_cycles_per_m``;
    the default band ``[0.01, 0.8]`` cycles/m is the one the paper's figure 10 implies (see
    ``docs/ride_study.md``).  The pothole is the project's own (the paper's MIRA pothole is
    not given): a sharp-edged rectangular hole seen through a rigid tyre of
    ``tyre_radius_m`` (:func:`ride_sim.road_envelope.envelope`) averaged over
    ``contact_length_m``.
    """

    roughness: float = _rule("positive", "road roughness G of eq 39 [m^2 (cycles/m)^(p-1)]",
                             5e-6)
    waviness: float = _rule("positive", "road waviness p of eq 39 [-]", 2.5)
    band_cycles_per_m: tuple[float, float] = _rule(
        "band", "synthesised spatial band [n_min, n_max] [cycles/m]", (0.01, 0.8))
    band_scaling: str = _rule(("choices", BAND_SCALINGS),
                              "speed sweep: 'temporal' keeps the band in Hz as at speed_m_s, "
                              "'spatial' keeps it in cycles/m (one road at every speed)",
                              "temporal")
    amplitudes: str = _rule(("choices", AMPLITUDE_METHODS),
                            "random-road synthesis (ride_sim.road_synthesis.random_road)",
                            "deterministic")
    speed_m_s: float = _rule("positive", "speed on the random road [m/s] (figure 10)", 20.0)
    length_m: float = _rule("positive", "length of random road evaluated [m]", 500.0)
    seeds: int = _rule(("int_range", 1, 10000), "road seeds per case (0 .. seeds-1)", 5)
    lead_in_s: float = _rule("non-negative", "road driven before the evaluated length (the "
                                             "same periodic road), discarded [s]", 3.0)
    sweep_speeds_m_s: tuple[float, ...] = _rule(
        "positive_list", "speeds of the speed sweep (figure 11) [m/s]",
        (5.0, 10.0, 15.0, 20.0, 25.0, 30.0, 35.0))
    pothole_speed_m_s: float = _rule("positive", "speed over the pothole [m/s] (figure 13)",
                                     10.0)
    pothole_depth_m: float = _rule("positive", "pothole depth [m]", 0.06)
    pothole_length_m: float = _rule("positive", "pothole length at the surface, edge to "
                                                "edge [m]", 0.75)
    tyre_radius_m: float = _rule("positive", "tyre radius of the enveloping model [m]", 0.3)
    contact_length_m: float = _rule("non-negative", "tyre contact length the enveloped "
                                                    "profile is averaged over [m] (0: none)",
                                    0.10)
    pothole_lead_in_m: float = _rule("positive", "flat road before the pothole [m]", 5.0)
    pothole_lead_out_m: float = _rule("positive", "flat road after the pothole [m]", 20.0)
    window_before_s: float = _rule("non-negative", "pothole r.m.s. window: start before "
                                                   "the leading edge [s]", 0.0)
    window_after_s: float = _rule("positive", "pothole r.m.s. window: end after the "
                                              "leading edge [s]", 0.2)


CLOCKS = ("realtime", "lockstep")


@dataclass(frozen=True)
class RideRunParams:
    """One closed-loop run of the ``ride_sim`` node (``damper-hil ride``; group ``ride``).

    The road is the random road of :class:`RoadParams` (eq 39, the minor road by default)
    synthesised over ``speed_m_s × duration_s``, driven after a ``lead_in_s`` taken from
    its end (periodic wrap) that the metrics leave out.
    """

    clock: str = _rule(("choices", CLOCKS),
                       "realtime: paced by the wall clock, the latest force held (HIL); "
                       "lockstep: as fast as possible, each sample waits for its force "
                       "(deterministic)", "realtime")
    duration_s: float = _rule("positive", "evaluated road time [s]", 20.0)
    speed_m_s: float = _rule("positive", "vehicle speed [m/s]", 20.0)
    seed: int = _rule(("int_range", 0, 2 ** 31 - 1), "random-road seed", 0)
    lead_in_s: float = _rule("non-negative", "road driven before the evaluated part [s]",
                             1.0)
    force_timeout_s: float = _rule(("range", 0.0, 600.0),
                                   "no force from the emulator for this long aborts the run "
                                   "[s]", 2.0)
    wait_for_emulator_s: float = _rule(("range", 0.0, 600.0),
                                       "wait this long for the emulator to become active "
                                       "(its first start compiles its kernels) [s]", 120.0)
    emulator_node: str = _rule("text", "the managed emulator node whose lifecycle state "
                                       "'active' starts the clock ('' = do not ask, only "
                                       "wait for the subscribers)", "damper_emulator")
    state_subscribers: int = _rule(("int_range", 1, 100),
                                   "start once this many subscribe to /damper/state (the "
                                   "emulator, plus a recorder that must not miss the start)",
                                   1)
    publish_ride_state: bool = _rule("bool", "publish /ride/state every sample", True)
    sched_fifo: bool = _rule("bool", "realtime clock: SCHED_FIFO for the loop thread when "
                                     "permitted", True)
    priority: int = _rule(("int_range", 1, 99), "SCHED_FIFO priority of the loop thread", 70)
    dds_priority: int = _rule(("int_range", 0, 99),
                              "SCHED_FIFO priority of the DDS middleware's threads (receive, "
                              "events) when permitted; below the loop's, so that the force "
                              "arrives on a busy machine (0: normal scheduling)", 60)
    metrics_file: str = _rule("text", "write the run's metrics here (JSON) at the end "
                                      "('' = do not)", "")


@dataclass(frozen=True)
class RideConfig:
    """A quarter car, its simulation settings and the ride studies' roads."""

    quarter_car: QuarterCarParams
    simulation: SimulationParams = SimulationParams()
    source: str = "<memory>"
    road: RoadParams = RoadParams()
    ride: RideRunParams = RideRunParams()


def _build(cls: type, data: Any, prefix: str, where: str) -> Any:
    return build_group(cls, {} if data is None else data, prefix, where, _check)


def validate_quarter_car(params: QuarterCarParams, where: str = "<memory>") -> QuarterCarParams:
    """Check every rule of an in-memory :class:`QuarterCarParams`; returns it."""
    for f in fields(params):
        _check(getattr(params, f.name), f, f"quarter_car.{f.name}", where)
    return params


def ride_config_from_mapping(doc: Any, source: str = "<memory>") -> RideConfig:
    """Build and validate a :class:`RideConfig` from a parsed params-file mapping.

    Other groups in the same ``ros__parameters`` (e.g. ``damper``) are ignored, so one file
    can configure both the emulator and the vehicle.
    """
    body = node_parameters(doc, source, "quarter_car")
    car = _build(QuarterCarParams, body["quarter_car"], "quarter_car", source)
    sim = _build(SimulationParams, body.get("simulation"), "simulation", source)
    road = _build(RoadParams, body.get("road"), "road", source)
    ride = _build(RideRunParams, body.get("ride"), "ride", source)
    return RideConfig(car, sim, source, road, ride)


def load_ride_config(path: str | Path | None = None) -> RideConfig:
    """Load and validate a quarter-car params file (default ``config/quarter_car.yaml``)."""
    path = Path(path) if path is not None else DEFAULT_QUARTER_CAR_FILE
    return ride_config_from_mapping(read_yaml(path), str(path))


def load_quarter_car(path: str | Path | None = None) -> QuarterCarParams:
    """The :class:`QuarterCarParams` of a params file (default ``config/quarter_car.yaml``)."""
    return load_ride_config(path).quarter_car


# --------------------------------------------------------------------------------------
# virtual damper tuning (ride_sim.tuning, docs/tune.md)

#: the valve constants tuned per direction (ValveParams fields)
VALVE_KEYS = ("preload_pa", "k_spring", "k_leak", "k_port")
#: the adaptive bypass diameters tuned with ``bypass`` (AdaptiveParams fields)
BYPASS_KEYS = ("comfort_bypass_diameter_m", "normal_bypass_diameter_m")


def _factor_band(what: str) -> Any:
    return _rule("band", f"factor range of {what} [-]", (0.5, 2.0))


@dataclass(frozen=True)
class TuneBounds:
    """Bounds of the design variables: ``[low, high]`` factors of the base damper's value
    (sampled log-uniformly)."""

    rebound_preload_pa: tuple[float, float] = _factor_band("the rebound blow-off preload")
    rebound_k_spring: tuple[float, float] = _factor_band("the rebound blow-off spring rate")
    rebound_k_leak: tuple[float, float] = _factor_band("the rebound leak restriction")
    rebound_k_port: tuple[float, float] = _factor_band("the rebound port restriction")
    compression_preload_pa: tuple[float, float] = _factor_band(
        "the compression blow-off preload")
    compression_k_spring: tuple[float, float] = _factor_band(
        "the compression blow-off spring rate")
    compression_k_leak: tuple[float, float] = _factor_band("the compression leak restriction")
    compression_k_port: tuple[float, float] = _factor_band("the compression port restriction")
    comfort_bypass_diameter_m: tuple[float, float] = _factor_band(
        "the comfort bypass diameter (with bypass: true)")
    normal_bypass_diameter_m: tuple[float, float] = _factor_band(
        "the normal bypass diameter (with bypass: true)")


@dataclass(frozen=True)
class TuneSettings:
    """What ``tune`` evaluates and how it searches."""

    designs: int = _rule(("int_range", 2, 1_000_000), "space-filling designs (Sobol)", 256)
    refine_rounds: int = _rule(("int_range", 0, 100),
                              "refinement rounds around the Pareto front", 2)
    refine_designs: int = _rule(("int_range", 1, 1_000_000),
                               "designs per refinement round", 64)
    refine_step: float = _rule(("range", 0.0, 1.0),
                              "first refinement's step, a fraction of each variable's log "
                              "range (halved every round) [-]", 0.1)
    road_classes: str = _rule("text", "ISO 8608 classes of the random roads, "
                                     "comma-separated", "A,B,C")
    speed_m_s: float = _rule("positive", "speed on the random roads [m/s]", 20.0)
    length_m: float = _rule("positive", "evaluated length of each random road [m]", 500.0)
    band_cycles_per_m: tuple[float, float] = _rule(
        "band", "synthesised spatial band of the random roads [cycles/m]", (0.01, 0.8))
    lead_in_s: float = _rule("non-negative", "road driven before the evaluated length, "
                                            "discarded [s]", 3.0)
    seed: int = _rule(("int_range", 0, 2**31 - 1), "seed of the roads and the design", 0)
    pothole: bool = _rule("bool", "also drive the ride studies' pothole (constraint only)",
                         True)
    bump_travel_m: float = _rule("positive", "suspension travel in bump from static, at the "
                                            "wheel [m]", 0.08)
    rebound_travel_m: float = _rule("positive", "suspension travel in rebound from static, "
                                               "at the wheel [m]", 0.08)
    bypass: bool = _rule("bool", "also tune the adaptive bypass diameters (the base damper "
                                "needs a damper.adaptive group)", False)
    chunk: int = _rule(("int_range", 1, 10_000),
                      "designs per task (a multiple of the damper step's 16 SIMD lanes)", 32)

    def variables(self) -> tuple[str, ...]:
        """The design variables (:class:`TuneBounds` field names) in use."""
        valves = tuple(f"{side}_{k}" for side in ("rebound", "compression")
                       for k in VALVE_KEYS)
        return valves + (BYPASS_KEYS if self.bypass else ())

    def classes(self) -> tuple[str, ...]:
        return tuple(c.strip().upper() for c in self.road_classes.split(",") if c.strip())
