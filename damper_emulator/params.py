"""Typed damper parameters, loaded and validated from ROS 2 params-file YAML.

A parameter file is a ROS 2 params file (``<node or /**>: ros__parameters: {...}``) or the
bare mapping inside it.  Two groups are read:

``damper``
    the physical parameters of Simms & Crolla (docs/model.md §2.3), SI units named in each key,
    with the optional sub-group ``damper.adaptive`` (the solenoid bypass of the softer
    settings, docs/model.md §6, :class:`AdaptiveParams`; without it there is no bypass and the
    valve command has no effect);
``numerics``
    the settings of the numerical implementation (valve look-up table, implicit solver).

Every value is checked; a bad file raises :class:`ParameterError` whose message is one line
naming the file, the key and the rule that was broken.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from damper_emulator.errors import one_line
from damper_emulator.model.valve import VALVE_FORMS
from damper_emulator.schema import (
    FieldSpec,
    ParameterError,
    build_group,
    check_value,
    field_spec,
    node_parameters,
    positive,
    read_yaml,
    required,
    rule,
)

if TYPE_CHECKING:  # pragma: no cover

    from damper_emulator.model.valve_table import ValveTable

DEFAULT_PARAMS_FILE = Path(__file__).resolve().parent.parent / "config" / "sport.yaml"
#: The virtual dyno's default specimen: a prototype of the sport damper, not its model.
PROTOTYPE_FILE = DEFAULT_PARAMS_FILE.with_name("prototype.yaml")


# --------------------------------------------------------------------------------------
# Parameter groups.  Each field's metadata holds its rule: ``positive``, ``range`` (lo, hi)
# exclusive of lo, or ``choices``.


@dataclass(frozen=True)
class AdaptiveParams:
    """The solenoid bypass of the adaptive damper's softer settings (docs/model.md §6;
    :mod:`damper_emulator.model.adaptive`): a short bore in parallel with the piston valve,
    ``Δp = (8πρνL Q + ρ/(2C_d²) Q|Q|)/A²``, open ``A_comfort`` at command 0, ``A_normal`` at
    0.5 and closed at 1 ('sport'), behind a first-order solenoid lag.  The oil viscosity is
    the damper's ``oil_kinematic_viscosity_m2_s``; the initial command is the emulator's
    ``emulator.valve_command``."""

    oil_density_kg_m3: float = rule("positive", "oil density ρ [kg/m³]")
    bypass_discharge_coefficient: float = rule(
        ("range", 0.0, 1.0), "discharge coefficient C_d of the bypass orifice [-]")
    bypass_length_m: float = rule("positive", "length L of the bypass bore [m] (its "
                                              "laminar, Hagen-Poiseuille loss)")
    comfort_bypass_diameter_m: float = rule(
        "non-negative", "bypass diameter open at command 0, 'comfort' [m]")
    normal_bypass_diameter_m: float = rule(
        "non-negative", "bypass diameter open at command 0.5, 'normal' [m]")
    solenoid_t63_s: float = rule(
        "non-negative", "solenoid time constant: 63 % of a command step after it [s] "
                        "(0: no lag)")

    @property
    def comfort_area_m2(self) -> float:
        return math.pi / 4.0 * self.comfort_bypass_diameter_m ** 2

    @property
    def normal_area_m2(self) -> float:
        return math.pi / 4.0 * self.normal_bypass_diameter_m ** 2


# --------------------------------------------------------------------------------------
# Model extensions (damper_emulator/model/extensions.py has the equations): effects
# the paper's model lacks, each an optional sub-group of ``damper.extensions``, off when
# absent.  The identification's ``diagnose`` fits them on top of identified parameters.


@dataclass(frozen=True)
class LugreFrictionParams:
    """LuGre friction with pre-sliding (Canudas de Wit et al. 1995) in place of eq 4's
    Coulomb term: bristle state ``ż = v − σ0 |v| z / g(v)``, ``g(v) = F_c + (F_s − F_c)
    exp(−(v/v_s)²)``, force ``σ0 z``."""

    coulomb_n: float = rule("non-negative", "sliding (Coulomb) friction F_c [N]")
    static_n: float = rule("non-negative", "static (break-away) friction F_s [N]")
    stribeck_velocity_m_s: float = rule("positive", "Stribeck velocity v_s [m/s]")
    bristle_stiffness_n_m: float = rule("positive", "pre-sliding (bristle) stiffness σ0 "
                                                    "[N/m]")


@dataclass(frozen=True)
class ViscosityTemperatureParams:
    """Oil viscosity falling with temperature, ``ν = ν_ref exp(−β (T − T_ref))``; the port
    and leak laws (eqs 8–9) scale with ``ν^(1/4)``, applied to the whole valve
    characteristic.  ``T`` is the measured temperature (data column) plus, with a heat
    capacity, the rise of a lumped heat model driven by the dissipated power."""

    temperature_coefficient_per_k: float = rule(
        "non-negative", "viscosity–temperature coefficient β [1/K]")
    reference_temperature_c: float = rule(
        ("closed", -60.0, 250.0), "temperature at which the valve parameters hold [°C]")
    heat_capacity_j_per_k: float = rule(
        "non-negative", "lumped heat capacity of oil and tube [J/K] (0: no heat model, the "
                        "measured temperature only)", 0.0)
    cooling_time_constant_s: float = rule(
        "positive", "time constant of cooling to ambient [s]", 600.0)


@dataclass(frozen=True)
class CavitationParams:
    """The rebound chamber cannot fall below the cavitation (vapour / gas-release) pressure:
    it is held there while a cavity exists, which refills before pressure builds again."""

    cavitation_pressure_pa: float = rule(
        "non-negative", "absolute pressure at which the oil cavitates [Pa]")


@dataclass(frozen=True)
class ValveLagParams:
    """Valve dynamics: the piston-valve flow follows its quasi-static value at the present
    Δp through a first-order lag (the blow-off disc opens late)."""

    time_constant_s: float = rule("positive", "valve opening time constant τ_v [s]")


@dataclass(frozen=True)
class SeriesComplianceParams:
    """A spring in series between the dyno's stroke and the damper (mount, bushes,
    fixture): the damper moves ``x − F/k``."""

    stiffness_n_m: float = rule("positive", "series (mount) stiffness k_m [N/m]")


@dataclass(frozen=True)
class EndStopParams:
    """End stops past a penetration ``δ`` of either stop, moving into it at ``v``:
    ``(k₁ δ + k δⁿ)(1 + η tanh(v / v_h)) + c δ v + c_h min(δ/δ_h, 1) v|v|`` pushing back
    towards the middle (an elastomer's linear and progressive stiffness and its
    hysteresis, which hardly depends on the speed, ``v_h`` = 5 mm/s; a damping growing
    with the penetration; a hydraulic stop's orifice, quadratic in the speed, engaging
    over its first ``δ_h``), the compression stop's times ``s``; without the optional
    terms the progressive ``k δ²`` of both stops alike."""

    rebound_position_m: float = rule(("closed", -1.0, 1.0),
                                     "stroke at which the rebound stop engages [m, ext +]")
    compression_position_m: float = rule(
        ("closed", -1.0, 1.0), "stroke at which the compression (bump) stop engages [m]")
    stiffness_n_m2: float = rule("positive", "stop coefficient k of k δⁿ [N/mⁿ; N/m² for "
                                             "the default n = 2]")
    linear_stiffness_n_m: float = rule("non-negative",
                                       "linear stiffness k₁ of k₁ δ [N/m]", 0.0)
    progressive_exponent: float = rule(("closed", 1.0, 6.0),
                                       "the exponent n of the progressive k δⁿ [-]", 2.0)
    hysteresis: float = rule(("closed", 0.0, 1.0),
                             "the elastomer's hysteresis η: its force rises by η into the "
                             "stop and falls by η out of it [-]", 0.0)
    damping_n_s_m2: float = rule("non-negative",
                                 "damping c of c δ v, growing with the penetration "
                                 "[N·s/m²]", 0.0)
    hydraulic_damping_n_s2_m2: float = rule(
        "non-negative", "a hydraulic stop's orifice damping c_h of c_h v|v|, in full past "
        "its engagement [N·s²/m²]", 0.0)
    hydraulic_engagement_m: float = rule(
        "positive", "the penetration δ_h over which the hydraulic damping grows in "
        "linearly (a cup's entry) [m]", 0.005)
    compression_scale: float = rule("positive",
                                    "the compression stop's force over the rebound stop's "
                                    "at the same penetration and speed [-]", 1.0)

    @property
    def plain(self) -> bool:
        """Whether only the progressive ``k δ²`` of both stops alike is in use."""
        return (self.linear_stiffness_n_m == 0.0 and self.damping_n_s_m2 == 0.0
                and self.hydraulic_damping_n_s2_m2 == 0.0
                and self.compression_scale == 1.0 and self.progressive_exponent == 2.0
                and self.hysteresis == 0.0)


@dataclass(frozen=True)
class AirEntrainmentParams:
    """Air bubbles in the rebound chamber's oil, isothermal: compressibility
    ``α + ε p_atm / p²``."""

    air_volume_fraction: float = rule(("range", 0.0, 0.5),
                                      "air volume fraction ε at atmospheric pressure [-]")


@dataclass(frozen=True)
class BypassGrooveParams:
    """A bypass groove in the pressure tube: an extra orifice in parallel with the piston
    valve (the law of :mod:`damper_emulator.model.adaptive`) open while the piston is over
    it, with linear ramps of 20 % of the half-length at its ends."""

    area_m2: float = rule("positive", "open area of the groove [m²]")
    center_m: float = rule(("closed", -1.0, 1.0), "stroke at the groove's centre [m]")
    half_length_m: float = rule("positive", "half of the groove's length [m]")
    land_length_m: float = rule("positive", "flow length over the piston land [m]", 5e-3)
    discharge_coefficient: float = rule(("range", 0.0, 1.0), "discharge coefficient [-]",
                                        0.7)
    oil_density_kg_m3: float = rule("positive", "oil density ρ [kg/m³]", 870.0)


@dataclass(frozen=True)
class GasHeatTransferParams:
    """Heat transfer between the gas and the tube: the gas compresses adiabatically (γ)
    and relaxes to the wall temperature with a thermal time constant (isothermal when
    slow, eq 3 when fast)."""

    thermal_time_constant_s: float = rule("positive", "gas thermal time constant τ_g [s]")


@dataclass(frozen=True)
class InertiaParams:
    """A mass between the load cell and the damper (a heavy rod end, an adapter, the
    damper's own moving parts on the load cell's side): the recorded force carries
    ``m ẍ`` beside the damper's."""

    mass_kg: float = rule("positive", "the moving mass m of m ẍ [kg]")


def _term(doc: str) -> Any:
    """A coefficient of the discovered term: any finite number, 0 (the feature unused) by
    default."""
    return rule("finite", doc, 0.0)


@dataclass(frozen=True)
class DiscoveredTermParams:
    """A term found by ``diagnose``'s discovery in what the library of effects left
    (:mod:`damper_emulator.model.discovered` has the features): coefficients times features
    of the motion and of the model's states, added to the force; with ``s = tanh(ẋ/v_s)``
    and ``F`` the model's force without the term."""

    acceleration_kg: float = _term("coefficient of ẍ (an inertia) [kg]")
    velocity_n_s_m: float = _term("coefficient of ẋ [N·s/m]")
    velocity_squared_n_s2_m2: float = _term("coefficient of ẋ|ẋ| [N·s²/m²]")
    velocity_cubed_n_s3_m3: float = _term("coefficient of ẋ³ [N·s³/m³]")
    smooth_sign_n: float = _term("coefficient of s = tanh(ẋ/v_s) [N]")
    stroke_n_m: float = _term("coefficient of x [N/m]")
    stroke_squared_n_m2: float = _term("coefficient of x² [N/m²]")
    stroke_cubed_n_m3: float = _term("coefficient of x³ [N/m³]")
    stroke_velocity_n_s_m2: float = _term("coefficient of x·ẋ [N·s/m²]")
    stroke_squared_velocity_n_s_m3: float = _term("coefficient of x²·ẋ [N·s/m³]")
    stroke_sign_n_m: float = _term("coefficient of x·s, a friction changing over the "
                                   "stroke [N/m]")
    stroke_squared_sign_n_m2: float = _term("coefficient of x²·s [N/m²]")
    abs_stroke_sign_n_m: float = _term("coefficient of |x|·s [N/m]")
    compression_pressure_sign_m2: float = _term(
        "coefficient of p_c·s, the gas pressure times the sign (a seal loaded by it) [m²]")
    rebound_pressure_sign_m2: float = _term("coefficient of p_r·s [m²]")
    pressure_drop_m2: float = _term("coefficient of p_r − p_c [m²]")
    energy_force_per_j: float = _term(
        "coefficient of E·F, E the energy dissipated since the start [1/J]")
    temperature_force_per_k: float = _term(
        "coefficient of (T − T_ref)·F, T the measured temperature [1/K]")
    profile_n_s_m: float = _term(
        "coefficient of exp(−(x − c)²/(2 w²))·ẋ, damping over a zone of the stroke [N·s/m]")
    lag_coefficient: float = _term("coefficient of y − F, y the force lagged by τ [-]")
    smooth_sign_velocity_m_s: float = rule("positive", "velocity scale v_s of the smooth "
                                                       "sign [m/s]", 0.005)
    reference_temperature_c: float = rule(("closed", -60.0, 250.0),
                                          "reference temperature T_ref [°C]", 25.0)
    profile_center_m: float = rule(("closed", -1.0, 1.0), "centre c of the zone [m]", 0.0)
    profile_width_m: float = rule("non-negative", "width w of the zone [m] (0: none)", 0.0)
    lag_time_constant_s: float = rule("positive", "time constant τ of the lag [s]", 0.005)


@dataclass(frozen=True)
class ExtensionParams:
    """``damper.extensions``: the model extensions in use (each absent = off)."""

    lugre_friction: LugreFrictionParams | None = rule("extension", "friction", None)
    viscosity_temperature: ViscosityTemperatureParams | None = rule("extension", "thermal",
                                                                     None)
    cavitation: CavitationParams | None = rule("extension", "cavitation", None)
    valve_lag: ValveLagParams | None = rule("extension", "valve_dynamics", None)
    series_compliance: SeriesComplianceParams | None = rule("extension", "compliance", None)
    end_stops: EndStopParams | None = rule("extension", "end_stop", None)
    air_entrainment: AirEntrainmentParams | None = rule("extension", "air_entrainment", None)
    bypass_groove: BypassGrooveParams | None = rule("extension", "position_dependent", None)
    gas_heat_transfer: GasHeatTransferParams | None = rule("extension", "gas_spring", None)
    inertia: InertiaParams | None = rule("extension", "inertia", None)
    discovered_term: DiscoveredTermParams | None = rule("extension", "discovered", None)

    def active(self) -> list[str]:
        """Names of the extensions in use."""
        return [f.name for f in fields(self) if getattr(self, f.name) is not None]


#: dataclass of each extension, by name
EXTENSION_TYPES: dict[str, type] = {
    "lugre_friction": LugreFrictionParams,
    "viscosity_temperature": ViscosityTemperatureParams,
    "cavitation": CavitationParams,
    "valve_lag": ValveLagParams,
    "series_compliance": SeriesComplianceParams,
    "end_stops": EndStopParams,
    "air_entrainment": AirEntrainmentParams,
    "bypass_groove": BypassGrooveParams,
    "gas_heat_transfer": GasHeatTransferParams,
    "inertia": InertiaParams,
    "discovered_term": DiscoveredTermParams,
}
#: family (CONTRACT ``diagnose`` JSON) of each extension
EXTENSION_FAMILIES: dict[str, str] = {f.name: f.metadata["doc"]
                                      for f in fields(ExtensionParams)}


@dataclass(frozen=True)
class ValveParams:
    """One direction of the piston valve (eqs 8–10, 28)."""

    k_leak: float = positive("leak restriction K_leak [kg/m^(27/4)], eq 9")
    k_port: float = positive("port restriction K_port [kg/m^(27/4)], eq 8")
    k_spring: float = positive("blow-off stiffness K_spring [kg^(3/2)/(s^2 m^(9/2))], eq 10")
    preload_pa: float = positive("blow-off preload Δp0 [Pa], eq 10")
    smoothing_g: float = positive("transition smoothing exponent G [-], eq 28")

    def __iter__(self) -> Iterator[float]:
        return iter((self.k_leak, self.k_port, self.k_spring, self.preload_pa, self.smoothing_g))


@dataclass(frozen=True)
class DamperParams:
    """Physical parameters of the mono-tube damper (docs/model.md §2.3)."""

    pressure_tube_length_m: float = positive("pressure tube length L_pt [m]")
    x0_m: float = positive("piston position at rest X0 [m] (rebound chamber length L_pt − X0)")
    rod_diameter_m: float = positive("piston rod diameter [m]")
    piston_diameter_m: float = positive("piston diameter [m]")
    gas_gamma: float = required(("closed", 1.0, 5.0 / 3.0),
                                "gas polytropic exponent γ [-], eq 3")
    oil_kinematic_viscosity_m2_s: float = positive("oil kinematic viscosity ν [m²/s]")
    oil_compressibility_per_pa: float = positive("oil compressibility α [1/Pa], eq 1")
    friction_force_n: float = required("non-negative", "Coulomb friction F_friction [N], eq 4")
    gas_volume_static_m3: float = positive("gas volume at the static position V_gas,static [m³]")
    gas_pressure_static_pa: float = positive(
        "gas pressure at the static position P_gas,static [Pa]")
    rebound: ValveParams = required("group", "rebound valve (Δp > 0)")
    compression: ValveParams = required("group", "compression valve (Δp < 0)")
    name: str = field(default="damper", metadata={"rule": "text", "doc": "damper name"})
    adaptive: AdaptiveParams | None = field(default=None, metadata={
        "rule": "adaptive", "doc": "solenoid bypass of the softer settings (docs/model.md §6); "
                                   "None: no bypass, the valve command has no effect"})
    extensions: ExtensionParams | None = field(default=None, metadata={
        "rule": "extensions", "doc": "effects the paper's model lacks; None: the "
                                     "paper's model"})

    @property
    def rod_area_m2(self) -> float:
        return math.pi / 4.0 * self.rod_diameter_m ** 2

    @property
    def piston_area_m2(self) -> float:
        return math.pi / 4.0 * self.piston_diameter_m ** 2

    @property
    def annulus_area_m2(self) -> float:
        """Rebound-chamber (annulus) area ``A_pt − A_rod`` [m²]."""
        return self.piston_area_m2 - self.rod_area_m2

    @property
    def static_force_n(self) -> float:
        """Force at rest, ``F_static = −A_rod P_gas,static`` (eq 30) [N]."""
        return -self.rod_area_m2 * self.gas_pressure_static_pa

    @property
    def max_extension_m(self) -> float:
        """Physical travel in extension: the rebound chamber length ``L_pt − X0`` [m]."""
        return self.pressure_tube_length_m - self.x0_m

    @property
    def max_compression_m(self) -> float:
        """Physical travel in compression until the gas volume vanishes (> 0) [m]."""
        return self.gas_volume_static_m3 / self.rod_area_m2


@dataclass(frozen=True)
class NumericsParams:
    """Settings of the numerical implementation (not physics)."""

    valve_form: str = field(default="cardano", metadata={
        "rule": ("choices", VALVE_FORMS),
        "doc": "open-valve solution: 'cardano' (eq 22 as published) or 'exact' (eq 19)"})
    valve_table_points: int = field(default=1024, metadata={
        "rule": ("int_range", 16, 1_000_000), "doc": "nodes of the inverse valve table"})
    valve_table_max_velocity_m_s: float = field(default=10.0, metadata={
        "rule": "positive", "doc": "damper velocity covered by the valve table [m/s]"})
    max_substep_s: float = field(default=5e-4, metadata={
        "rule": "positive", "doc": "longest implicit sub-step of the pressure equation [s]"})
    settle_gap_s: float = field(default=0.1, metadata={
        "rule": "positive", "doc": "a step longer than this (a gap in the input) restarts "
        "from quasi-steady equilibrium at the new sample [s]"})
    newton_tolerance: float = field(default=1e-10, metadata={
        "rule": "positive",
        "doc": "convergence of the implicit solve, in the table coordinate [-]"})
    newton_max_iterations: int = field(default=60, metadata={
        "rule": ("int_range", 4, 1000), "doc": "iteration cap of the implicit solve"})
    travel_margin_m: float = field(default=1e-4, metadata={
        "rule": "positive", "doc": "the stepper clamps stroke this far inside the travel [m]"})


@dataclass(frozen=True)
class ModelConfig:
    """A damper and the numerics that evaluate it."""

    damper: DamperParams
    numerics: NumericsParams = NumericsParams()
    source: str = "<memory>"

    def replace_damper(self, **changes: Any) -> ModelConfig:
        """A copy with some damper parameters changed (validated)."""
        cfg = dataclasses.replace(self, damper=dataclasses.replace(self.damper, **changes))
        validate(cfg)
        return cfg


# --------------------------------------------------------------------------------------
# Loading


#: the group type of each nested rule
_NESTED: dict[str, Callable[[dataclasses.Field[Any]], type]] = {
    "group": lambda f: ValveParams, "adaptive": lambda f: AdaptiveParams,
    "extensions": lambda f: ExtensionParams,
    "extension": lambda f: EXTENSION_TYPES[f.name]}


def field_specs(cls: type, prefix: str) -> list[FieldSpec]:
    """Every parameter of the group ``cls`` (a dataclass of :func:`rule` fields), nested
    groups flattened to dotted keys under ``prefix`` (``damper.rebound.k_leak``), in
    declaration order."""
    out: list[FieldSpec] = []
    for f in fields(cls):
        key = f"{prefix}.{f.name}" if prefix else f.name
        nested = _NESTED.get(f.metadata["rule"]) if isinstance(f.metadata["rule"], str) \
            else None
        if nested is not None:
            out.extend(field_specs(nested(f), key))
        else:
            out.append(field_spec(f, key))
    return out


def _build(cls: type, data: Any, prefix: str, where: str) -> Any:
    return build_group(cls, data, prefix, where, _convert)


def _convert(raw: Any, f: dataclasses.Field[Any], key: str, where: str) -> Any:
    if f.metadata["rule"] == "group":
        return _build(ValveParams, raw, key, where)
    if f.metadata["rule"] == "adaptive":
        return build_group(AdaptiveParams, raw, key, where, check_value)
    if f.metadata["rule"] == "extensions":
        return build_group(ExtensionParams, raw, key, where, _convert)
    if f.metadata["rule"] == "extension":
        if raw is None:
            return None
        return build_group(EXTENSION_TYPES[f.name], raw, key, where, check_value)
    return check_value(raw, f, key, where)


def _check_fields(obj: Any, prefix: str, where: str) -> None:
    """Every value's own rule (:func:`check_value`), sub-groups included; the first one
    broken raises."""
    for f in fields(obj):
        value = getattr(obj, f.name)
        if f.metadata["rule"] == "group":
            _check_fields(value, f"{prefix}.{f.name}", where)
        elif f.metadata["rule"] == "extensions":
            check_extensions(value, where)
        elif f.metadata["rule"] != "adaptive":
            check_value(value, f, f"{prefix}.{f.name}", where)


def check_extensions(ext: ExtensionParams | None, where: str) -> None:
    """Every rule of a ``damper.extensions`` group (one-line :class:`ParameterError`)."""
    if ext is None:
        return
    if not isinstance(ext, ExtensionParams):
        raise ParameterError(f"{where}: damper.extensions must be a mapping of "
                             f"{', '.join(EXTENSION_TYPES)}")
    for f in fields(ext):
        group = getattr(ext, f.name)
        if group is not None:
            if not isinstance(group, EXTENSION_TYPES[f.name]):
                names = ", ".join(g.name for g in fields(EXTENSION_TYPES[f.name]))
                raise ParameterError(f"{where}: damper.extensions.{f.name} must be a mapping "
                                     f"of {names}")
            _check_fields(group, f"damper.extensions.{f.name}", where)


def validate(cfg: ModelConfig) -> None:
    """Check every rule; raise :class:`ParameterError` for the first one broken.

    Rules: positive lengths, areas, volumes, pressures and valve constants; rod thinner than
    the piston; ``X0 < L_pt``; ``1 <= γ <= 5/3``; a valve characteristic that is strictly
    increasing (hence invertible) over the table range, checked by building the table.
    """
    where = cfg.source
    _check_fields(cfg.damper, "damper", where)
    _check_fields(cfg.numerics, "numerics", where)
    d = cfg.damper
    if not d.rod_diameter_m < d.piston_diameter_m:
        raise ParameterError(
            f"{where}: damper.rod_diameter_m = {d.rod_diameter_m:g} must be smaller than "
            f"damper.piston_diameter_m = {d.piston_diameter_m:g}")
    if not d.x0_m < d.pressure_tube_length_m:
        raise ParameterError(
            f"{where}: damper.x0_m = {d.x0_m:g} must be smaller than "
            f"damper.pressure_tube_length_m = {d.pressure_tube_length_m:g}")
    if not d.oil_compressibility_per_pa * d.gas_pressure_static_pa < 1.0:
        raise ParameterError(
            f"{where}: damper.oil_compressibility_per_pa × gas_pressure_static_pa must be "
            "below 1 (eq 1: the oil volume would vanish)")
    if d.adaptive is not None:
        _check_adaptive(d, where)
    # The inverse valve table checks monotonicity of both characteristics.
    from damper_emulator.model.valve_table import ValveTableError

    try:
        valve_tables(cfg)
    except ValveTableError as exc:
        raise ParameterError(f"{where}: {exc}") from None
    except ArithmeticError as exc:  # a division by zero or overflow in the valve laws
        raise ParameterError(f"{where}: the valve characteristics cannot be evaluated "
                             f"({one_line(exc, with_type=True)}): a valve parameter is "
                             "far outside its physical range") from None


def valve_tables(cfg: ModelConfig) -> tuple[ValveTable, ValveTable]:
    """The inverse valve tables (rebound, compression) of ``cfg``'s valves (docs/model.md
    §2.1; :func:`damper_emulator.model.valve_table.build_valve_tables`).

    Raises
    ------
    damper_emulator.model.valve_table.ValveTableError
        A characteristic that is not finite and strictly increasing up to the table's
        largest velocity.
    """
    from damper_emulator.model.valve_table import build_valve_tables

    d, n = cfg.damper, cfg.numerics
    return build_valve_tables(d.rebound, d.compression, d.annulus_area_m2,
                              d.oil_kinematic_viscosity_m2_s, n.valve_form,
                              n.valve_table_points, n.valve_table_max_velocity_m_s)


def _check_adaptive(d: DamperParams, where: str) -> None:
    """The rules of ``damper.adaptive`` (one-line :class:`ParameterError` naming the key):
    each value's own rule, comfort the softest setting (its bypass at least as wide as
    normal's) and the bypass narrower than the piston."""
    a = d.adaptive
    if not isinstance(a, AdaptiveParams):
        raise ParameterError(f"{where}: damper.adaptive must be a mapping of "
                             f"{', '.join(f.name for f in fields(AdaptiveParams))}")
    for f in fields(AdaptiveParams):
        check_value(getattr(a, f.name), f, f"damper.adaptive.{f.name}", where)
    if not a.normal_bypass_diameter_m <= a.comfort_bypass_diameter_m:
        raise ParameterError(
            f"{where}: damper.adaptive.normal_bypass_diameter_m = "
            f"{a.normal_bypass_diameter_m:g} must not exceed "
            f"damper.adaptive.comfort_bypass_diameter_m = {a.comfort_bypass_diameter_m:g} "
            "(comfort is the softest setting)")
    if not a.comfort_bypass_diameter_m < d.piston_diameter_m:
        raise ParameterError(
            f"{where}: damper.adaptive.comfort_bypass_diameter_m = "
            f"{a.comfort_bypass_diameter_m:g} must be smaller than damper.piston_diameter_m "
            f"= {d.piston_diameter_m:g}")


def config_from_mapping(doc: Any, source: str = "<memory>") -> ModelConfig:
    """Build and validate a :class:`ModelConfig` from a parsed params-file mapping."""
    body = node_parameters(doc, source)
    damper = _build(DamperParams, body["damper"], "damper", source)
    numerics = _build(NumericsParams, body.get("numerics") or {}, "numerics", source)
    cfg = ModelConfig(damper=damper, numerics=numerics, source=source)
    validate(cfg)
    return cfg


def load_config(path: str | Path | None = None) -> ModelConfig:
    """Load and validate a parameter file (default: ``config/sport.yaml``)."""
    path = Path(path) if path is not None else DEFAULT_PARAMS_FILE
    return config_from_mapping(read_yaml(path), str(path))


def with_extensions(cfg: ModelConfig, extensions: Mapping[str, Mapping[str, Any]],
                    base_changes: Mapping[str, Any] | None = None) -> ModelConfig:
    """``cfg`` with the extensions ``{name: parameters}`` (only those) and the damper's
    base parameters changed by ``base_changes``; validated.

    Raises
    ------
    ParameterError
        An unknown extension, or a value outside its rule.
    """
    damper = cfg.damper
    if base_changes:
        damper = dataclasses.replace(damper, **base_changes)
    for name in extensions:
        if name not in EXTENSION_TYPES:
            raise ParameterError(f"unknown extension {name!r} (one of "
                                 f"{', '.join(EXTENSION_TYPES)})")
    groups = {name: EXTENSION_TYPES[name](**params) for name, params in extensions.items()}
    damper = dataclasses.replace(damper, extensions=ExtensionParams(**groups) if groups
                                 else None)
    out = dataclasses.replace(cfg, damper=damper)
    validate(out)
    return out


def config_to_mapping(cfg: ModelConfig, node: str = "/**") -> dict[str, Any]:
    """The params-file mapping of a configuration (inverse of :func:`config_from_mapping`)."""
    damper = dataclasses.asdict(cfg.damper)
    if damper.get("adaptive") is None:
        damper.pop("adaptive", None)
    ext = damper.get("extensions")
    if ext is None:
        damper.pop("extensions", None)
    else:
        damper["extensions"] = {k: v for k, v in ext.items() if v is not None}
    return {node: {"ros__parameters": {"damper": damper,
                                       "numerics": dataclasses.asdict(cfg.numerics)}}}


def save_config(cfg: ModelConfig, path: str | Path, node: str = "/**") -> None:
    """Write a configuration as a ROS 2 params file (floats with signed exponents)."""
    Path(path).write_text(config_yaml(cfg, node))


def config_yaml(cfg: ModelConfig, node: str = "/**") -> str:
    """A configuration as the text of a ROS 2 params file (:func:`save_config`).  PyYAML's
    safe representer writes each float with the shortest digits that read back to the
    same double, and a point in the mantissa where there is an exponent (``1.0e-20``:
    YAML 1.1 and ROS 2's parser read ``1e-20`` as a string)."""
    return yaml.safe_dump(config_to_mapping(cfg, node), sort_keys=False)


