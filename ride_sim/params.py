"""Typed quarter-car and simulation parameters, loaded from a ROS 2 params file.

The file (default ``config/quarter_car.yaml``) has the layout of ``config/sport.yaml``::

    /**:
      ros__parameters:
        quarter_car: {sprung_mass_kg: ..., ...}
        simulation: {step_s: ..., ...}

(or the bare mapping inside ``ros__parameters``).  The quarter car is the two-mass model of
Simms & Crolla eq 38 (``../shared/MODEL.md`` §5); its values are the paper's front corner
(Figure 8).  Every value is checked; a bad file raises
:class:`damper_emulator.params.ParameterError` whose message is one line naming the file,
the key and the rule that was broken.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

from damper_emulator.params import ParameterError, read_yaml

#: Default parameter file: the paper's front quarter car.
DEFAULT_QUARTER_CAR_FILE = Path(__file__).resolve().parent.parent / "config" / "quarter_car.yaml"

#: Damper kinds understood by :func:`ride_sim.dampers.make_damper`.
DAMPER_KINDS = ("linear", "14speed", "incompressible", "compressible", "nonlinear")


def _rule(rule: Any, doc: str, default: Any = dataclasses.MISSING) -> Any:
    return field(default=default, metadata={"rule": rule, "doc": doc})


@dataclass(frozen=True)
class QuarterCarParams:
    """Two-mass quarter car, eq 38 (MODEL.md §5), SI units.

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
                                       "points of the N-speed test table", 14)


@dataclass(frozen=True)
class RideConfig:
    """A quarter car and its simulation settings."""

    quarter_car: QuarterCarParams
    simulation: SimulationParams = SimulationParams()
    source: str = "<memory>"


def _check(value: Any, f: dataclasses.Field, key: str, where: str) -> Any:
    """Coerce and check one value; raise a one-line :class:`ParameterError`."""
    rule, doc = f.metadata["rule"], f.metadata["doc"]
    kind = rule[0] if isinstance(rule, tuple) else rule
    if kind == "choices":
        if not isinstance(value, str):
            raise ParameterError(f"{where}: {key} must be a string, got {value!r}")
        if value not in rule[1]:
            raise ParameterError(f"{where}: {key} = {value!r} must be one of "
                                 f"{', '.join(rule[1])}")
        return value
    if kind == "int_range":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(f"{where}: {key} must be an integer, got {value!r}")
        if not rule[1] <= value <= rule[2]:
            raise ParameterError(f"{where}: {key} = {value} must lie in "
                                 f"[{rule[1]}, {rule[2]}] ({doc})")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(f"{where}: {key} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f"{where}: {key} = {value} must be finite ({doc})")
    if kind == "positive" and not value > 0:
        raise ParameterError(f"{where}: {key} = {value:g} must be positive ({doc})")
    if kind == "non-negative" and not value >= 0:
        raise ParameterError(f"{where}: {key} = {value:g} must not be negative ({doc})")
    if kind == "range" and not rule[1] < value <= rule[2]:
        raise ParameterError(f"{where}: {key} = {value:g} must lie in "
                             f"({rule[1]:g}, {rule[2]:g}] ({doc})")
    return value


def _build(cls: type, data: Any, prefix: str, where: str) -> Any:
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ParameterError(f"{where}: {prefix} must be a mapping")
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ParameterError(f"{where}: unknown parameter {prefix}.{unknown[0]}")
    values = {}
    for f in fields(cls):
        key = f"{prefix}.{f.name}"
        if f.name not in data:
            if f.default is dataclasses.MISSING:
                raise ParameterError(f"{where}: missing parameter {key} ({f.metadata['doc']})")
            continue
        values[f.name] = _check(data[f.name], f, key, where)
    return cls(**values)


def validate_quarter_car(params: QuarterCarParams, where: str = "<memory>") -> QuarterCarParams:
    """Check every rule of an in-memory :class:`QuarterCarParams`; returns it."""
    for f in fields(params):
        _check(getattr(params, f.name), f, f"quarter_car.{f.name}", where)
    return params


def _node_parameters(doc: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(doc, Mapping):
        raise ParameterError(f"{where}: expected a mapping at the top level")
    if "quarter_car" in doc:
        return doc
    for body in doc.values():
        if isinstance(body, Mapping) and isinstance(body.get("ros__parameters"), Mapping):
            if "quarter_car" in body["ros__parameters"]:
                return body["ros__parameters"]
    raise ParameterError(f"{where}: no 'quarter_car' parameters found (expected "
                         "'<node>: ros__parameters: quarter_car: ...' or 'quarter_car: ...')")


def ride_config_from_mapping(doc: Any, source: str = "<memory>") -> RideConfig:
    """Build and validate a :class:`RideConfig` from a parsed params-file mapping.

    Other groups in the same ``ros__parameters`` (e.g. ``damper``) are ignored, so one file
    can configure both the emulator and the vehicle.
    """
    body = _node_parameters(doc, source)
    car = _build(QuarterCarParams, body["quarter_car"], "quarter_car", source)
    sim = _build(SimulationParams, body.get("simulation"), "simulation", source)
    return RideConfig(car, sim, source)


def load_ride_config(path: str | Path | None = None) -> RideConfig:
    """Load and validate a quarter-car params file (default ``config/quarter_car.yaml``)."""
    path = Path(path) if path is not None else DEFAULT_QUARTER_CAR_FILE
    return ride_config_from_mapping(read_yaml(path), str(path))


def load_quarter_car(path: str | Path | None = None) -> QuarterCarParams:
    """The :class:`QuarterCarParams` of a params file (default ``config/quarter_car.yaml``)."""
    return load_ride_config(path).quarter_car
