"""The candidate effects ``diagnose`` fits: one per extension of
:mod:`damper_emulator.model.extensions`, with bounded parameters and start values derived
from physics and from the identification data.

Every bound and start is stated in :func:`candidates` with its reason.  Parameters are
searched in log space where they are scales (stiffnesses, time constants, areas) and in
linear space where they are positions; positions also get several starts (the fit of an
engagement point is not convex).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.errors import UserError
from damper_emulator.params import EXTENSION_FAMILIES, ModelConfig

#: Friction scale of the friction candidate's bounds when the identified friction is
#: smaller (an identification can end with none) [N]
MIN_FRICTION_SCALE_N = 10.0
#: A temperature column counts as informative when its values span at least this [K].
MIN_TEMPERATURE_SPAN_K = 2.0
#: Viscosity–temperature coefficient held when no temperature is measured [1/K]: mineral
#: damper oils halve their kinematic viscosity about every 25 K (ln 2 / 25).
TYPICAL_VISCOSITY_COEFFICIENT_PER_K = math.log(2.0) / 25.0
#: The end stops' re-identification leaves out samples farther than this fraction of the
#: tested stroke from its middle (the outer half of the stroke).
OUTER_STROKE_FRACTION = 0.25
#: Compression forces within this fraction of a file's largest count as a cavity's
#: plateau (and its shoulders) for the cavitation's re-identification: on the sport
#: damper with a cavity at 20 kPa this leaves the compression valve's blow-off below the
#: plateau in the fit, and the valve comes back within 7 % (benchmarks/diagnose_bench.py).
CAVITY_PLATEAU_FRACTION = 0.85
#: Cooling time constant of a damper body held in the heat model [s] (order of magnitude
#: of a dyno-mounted damper in still air; the fit is over minutes, so it matters little).
TYPICAL_COOLING_TIME_S = 600.0


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter: ``name`` as in the extension's parameter group (or a derived
    name that ``Candidate.fields`` maps), bounds, start value, search scale and unit."""

    name: str
    lo: float
    hi: float
    start: float
    log: bool = True
    unit: str = ""
    #: its low end is the form without it (no force within the tested stroke): held
    #: there where the fit files do not determine it (``joint_fit``'s step 5)
    optional: bool = False
    #: the optional parameter this one only shapes (an engagement length of a damping):
    #: held at its start with it
    part_of: str | None = None

    def to_internal(self, value: float) -> float:
        return math.log10(value) if self.log else value

    def from_internal(self, u: float) -> float:
        return 10.0 ** u if self.log else u

    @property
    def bounds(self) -> tuple[float, float]:
        return self.to_internal(self.lo), self.to_internal(self.hi)


@dataclass(frozen=True)
class Candidate:
    """An extension with its free parameters.

    ``fields(values)`` turns fitted values (by parameter name) into the extension's
    parameter group; ``extra_starts`` are further start vectors (values, in parameter
    order) for non-convex fits."""

    effect: str
    parameters: tuple[Parameter, ...]
    fields: Callable[[Mapping[str, float]], dict[str, float]]
    extra_starts: tuple[tuple[float, ...], ...] = ()
    note: str = ""
    #: where the effect may act whatever its parameters (``MeasuredData -> mask``): the
    #: samples a re-identification of the paper's parameters leaves out for it
    #: (:func:`damper_emulator.diagnose.joint.joint_fit`); ``None``: found by simulation
    may_act: Callable[[MeasuredData], np.ndarray] | None = None
    #: the configuration the staged re-identification runs with instead of the
    #: identified one (``ModelConfig -> ModelConfig``), for an effect that changes what a
    #: stage's closed form assumes; ``None``: the identified configuration
    identify_as: Callable[[ModelConfig], ModelConfig] | None = None
    #: for a later effect (others accepted first): the paper's parameters it takes from
    #: that re-identification, the rest of the present model kept (the staged fits know
    #: nothing of the accepted effects, and would put them into the valves again); empty:
    #: a later effect is re-identified as any other
    identify_keeps: tuple[str, ...] = ()
    #: where it acts, the effect holds the force at a level that trades with the friction
    #: at speed (a cavity's plateau, ``p_gas A_pt − p_cav A_annulus`` less the friction):
    #: its re-identification searches the friction at speed (``joint_fit``)
    friction_coupled: bool = False
    #: how many of the screened starts the pre-fit goes on from (the better end kept):
    #: more than one where positions make the fit multimodal (an end stop's engagement
    #: screened best from a start that ends at 23 mm for a stop at 35 mm, cost 39 against
    #: 1.4)
    prefit_keep: int = 1
    #: start vectors of a form of the effect of its own (a hydraulic stop's orifice on,
    #: beside the elastomer's starts): each goes on to the pre-fit whatever the
    #: screening, whose first evaluations cannot judge one form against another (on
    #: elastomer stops, the hydraulic start screened at a cost of 3·10⁴ against 144 and
    #: pre-fitted best, 2.4 against 23; the start that screened best ended 11 mm off)
    form_starts: tuple[tuple[float, ...], ...] = ()
    #: parameters no longer free and their values (:meth:`holding`)
    held: Mapping[str, float] = field(default_factory=dict)
    #: where the fit files leave a part of the effect's law undetermined
    #: (``(MeasuredData, fitted values) -> mask``), and why (:attr:`limit`): a held-out
    #: residual there neither credits nor blames the effect
    #: (:mod:`damper_emulator.diagnose.undetermined`); ``None``: nowhere
    undetermined: Callable[[MeasuredData, Mapping[str, float]], np.ndarray] | None = None
    limit: str = ""
    family: str = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "family", EXTENSION_FAMILIES[self.effect])

    @property
    def relative_cost(self) -> int:
        """A rough rank of this candidate's fit cost: its start vectors times its
        parameters (the multi-start pre-fit), more when it re-identifies the damper (and
        more again when it searches the friction at speed doing so).  The
        longest fits are started first so that a round does not end on one alone."""
        reidentifies = self.may_act is not None or self.identify_as is not None
        searches = 4 if self.friction_coupled else 1  # joint.search_friction's tries
        return ((len(self.starts()) + len(self.form_starts)) * len(self.parameters)
                + (3 * searches if reidentifies else 0))

    def holding(self, names: Collection[str]) -> Candidate:
        """This candidate with its optional parameters ``names`` held at their low ends
        (their forms left out) and the parameters that are ``part_of`` them at their
        starts: no longer free, their values in :attr:`fields`."""
        held = {p.name: (p.lo if p.name in names else p.start) for p in self.parameters
                if p.name in names or p.part_of in names}
        keep = [k for k, p in enumerate(self.parameters) if p.name not in held]
        fields = self.fields
        return dataclasses.replace(
            self, parameters=tuple(self.parameters[k] for k in keep),
            fields=lambda values: fields({**values, **held}), held={**self.held, **held},
            extra_starts=tuple(tuple(s[k] for k in keep) for s in self.extra_starts),
            form_starts=tuple(tuple(s[k] for k in keep) for s in self.form_starts))

    def settled(self, values: Mapping[str, float]) -> Candidate:
        """This candidate as an accepted effect fitted to ``values``: its optional
        parameters that fit left at their low ends held there (:meth:`holding`), so that
        later fits neither free nor hold them again."""
        return self.holding({p.name for p in self.parameters
                             if p.optional and values.get(p.name) == p.lo})

    def starts(self, form: bool = False) -> list[np.ndarray]:
        """Start vectors in the internal (search) coordinates (``form``: the
        :attr:`form_starts`)."""
        vecs = (list(self.form_starts) if form
                else [tuple(p.start for p in self.parameters), *self.extra_starts])
        out = []
        for vec in vecs:
            u = [p.to_internal(min(max(v, p.lo), p.hi)) for p, v in zip(self.parameters, vec)]
            out.append(np.array(u))
        return out


def _with(fixed: Mapping[str, float]) -> Callable[[Mapping[str, float]], dict[str, float]]:
    return lambda values: {**fixed, **values}


def temperature_stats(data: Sequence[MeasuredData]) -> tuple[float, float, float] | None:
    """``(mean, lowest, highest)`` [°C] of the temperature columns of ``data``, or ``None``
    when no file has one."""
    temps = [d.temperature for d in data if d.temperature is not None]
    if not temps:
        return None
    allt = np.concatenate(temps)
    return float(np.mean(allt)), float(np.min(allt)), float(np.max(allt))


#: the gas spring's parameters (eq 3) that an isothermal quasi-static fit (eq 37 with
#: γ = 1) gives a later gas that exchanges heat
GAS_PARAMETERS = ("gas_pressure_static_pa", "gas_volume_static_m3")


def isothermal_gas(cfg: ModelConfig) -> ModelConfig:
    """``cfg`` with an isothermal gas spring (γ = 1 in eq 3)."""
    return dataclasses.replace(cfg, damper=dataclasses.replace(cfg.damper, gas_gamma=1.0))


@dataclass(frozen=True)
class Scales:
    """What the candidates' bounds and starts are derived from: the identified damper
    ``cfg`` and the identification files."""

    cfg: ModelConfig
    fit_data: Sequence[MeasuredData]

    @property
    def x_lo(self) -> float:
        return min(float(np.min(r.displacement)) for r in self.fit_data)

    @property
    def x_hi(self) -> float:
        return max(float(np.max(r.displacement)) for r in self.fit_data)

    @property
    def span(self) -> float:
        """The tested stroke [m]."""
        return max(self.x_hi - self.x_lo, 1e-3)

    @property
    def friction(self) -> float:
        """The friction's scale: the identified friction, at least
        :data:`MIN_FRICTION_SCALE_N` [N]."""
        return max(self.cfg.damper.friction_force_n, MIN_FRICTION_SCALE_N)

    @property
    def oil_stiffness(self) -> float:
        """The rebound chamber's oil stiffness at rest, ``A²/(V α)`` [N/m]: the scale of
        any compliance."""
        d = self.cfg.damper
        return d.annulus_area_m2 / (d.max_extension_m * d.oil_compressibility_per_pa)

    @property
    def v_max(self) -> float:
        """The files' largest speed [m/s]."""
        return max(float(np.max(speed(r))) for r in self.fit_data)


def speed(data: MeasuredData) -> np.ndarray:
    """``|ẋ|`` [m/s] of a file, its displacement differentiated."""
    out: np.ndarray = np.abs(np.gradient(data.displacement, data.time))
    return out


def _friction(s: Scales) -> Candidate:
    """Friction: Coulomb level around the identified friction; break-away up to 4× it;
    Stribeck velocity 0.1 mm/s .. 0.1 m/s; bristle stiffness so that the pre-sliding
    travel F/σ0 lies between 1 µm and 10 mm."""
    f0 = s.friction
    return Candidate(
        "lugre_friction",
        (Parameter("coulomb_n", 0.2 * f0, 3.0 * f0 + 20.0, f0, False, "N"),
         Parameter("static_ratio", 1.0, 4.0, 1.5, False, "-"),
         Parameter("stribeck_velocity_m_s", 1e-4, 0.1, 0.01, True, "m/s"),
         Parameter("bristle_stiffness_n_m", f0 / 1e-2, f0 / 1e-6, f0 / 2e-4, True, "N/m")),
        lambda v: {"coulomb_n": v["coulomb_n"], "static_n": v["coulomb_n"] * v["static_ratio"],
                   "stribeck_velocity_m_s": v["stribeck_velocity_m_s"],
                   "bristle_stiffness_n_m": v["bristle_stiffness_n_m"]},
        # second start: close to the identified Coulomb friction (no Stribeck, stiff)
        extra_starts=((f0, 1.0, 0.01, f0 / 2e-6),))


def _thermal(s: Scales) -> Candidate | None:
    """Thermal: with a measured temperature, β between 0 and 0.1 /K (oils: 0.02-0.04) and
    the temperature at which the identified valves hold within the measured range
    (± 10 K: the identification averaged over whatever temperatures its files had);
    without, β held at a typical oil's and the lumped heat capacity fitted (100 J/K, a
    few grams of oil, .. 100 kJ/K, far more than any damper).  A temperature column that
    does not move says the oil did not warm: no thermal candidate (a drifting load-cell
    zero was named thermal through the heat model)."""
    temp = temperature_stats(s.fit_data)
    if temp is not None and temp[2] - temp[1] >= MIN_TEMPERATURE_SPAN_K:
        t_lo, t_hi = temp[1], temp[2]
        return Candidate(
            "viscosity_temperature",
            (Parameter("temperature_coefficient_per_k", 1e-4, 0.1, 0.02, True, "1/K"),
             Parameter("reference_temperature_c", t_lo - 10.0, t_hi + 10.0, temp[0], False,
                       "°C")),
            _with({}), note="driven by the measured temperature")
    if temp is not None:
        return None
    return Candidate(
        "viscosity_temperature",
        (Parameter("heat_capacity_j_per_k", 100.0, 1e5, 2000.0, True, "J/K"),),
        _with({"reference_temperature_c": 25.0,
               "temperature_coefficient_per_k": TYPICAL_VISCOSITY_COEFFICIENT_PER_K,
               "cooling_time_constant_s": TYPICAL_COOLING_TIME_S}),
        note="no measured temperature: heated by the dissipated power, β held at "
             f"{TYPICAL_VISCOSITY_COEFFICIENT_PER_K:.4f} /K")


def _cavitation(s: Scales) -> Candidate:
    """Cavitation: vapour pressure (~2 kPa) up to gas-release pressures near 1 bar and a
    little beyond; several starts because below the lowest pressure reached it does
    nothing.  A cavity opens only when the compression valve's drop exceeds
    ``p_gas − p_cav``, i.e. (eq 1, rebound chamber at ``p_cav ≤ p_hi``) where the damper
    pushes out with more than ``p_gas A_rod + (p_gas − p_hi) A_annulus``; an open cavity
    then holds the force on a plateau (``p_gas A_piston − p_cav A_annulus``) whatever the
    speed.  The re-identification fits the valves without the samples that are both (on
    the plateau the identified compression valve would otherwise go soft to follow it)."""
    d = s.cfg.damper
    p_hi = 0.5 * d.gas_pressure_static_pa
    f_cavity = (d.gas_pressure_static_pa * d.rod_area_m2
                + (d.gas_pressure_static_pa - p_hi) * d.annulus_area_m2)

    def may_cavitate(data: MeasuredData) -> np.ndarray:
        push = -data.force
        return (push >= f_cavity) & (push >= CAVITY_PLATEAU_FRACTION * float(np.max(push)))

    return Candidate(
        "cavitation", (Parameter("cavitation_pressure_pa", 1e3, p_hi, 2e4, True, "Pa"),),
        _with({}), extra_starts=((1e5,), (min(4e5, 0.5 * p_hi),)), may_act=may_cavitate,
        friction_coupled=True)


def _valve_lag(s: Scales) -> Candidate:
    """Valve dynamics: opening time constants from 10 µs to 50 ms."""
    return Candidate(
        "valve_lag", (Parameter("time_constant_s", 1e-5, 0.05, 2e-3, True, "s"),), _with({}),
        extra_starts=((2e-4,),))


def _compliance(s: Scales) -> Candidate:
    """Compliance: a series spring from 1/100 to 1000 × the oil column's stiffness."""
    k_oil = s.oil_stiffness
    return Candidate(
        "series_compliance",
        (Parameter("stiffness_n_m", k_oil / 100.0, k_oil * 1000.0, k_oil, True, "N/m"),),
        _with({}), extra_starts=((k_oil * 10.0,),))


#: A hydraulic stop's orifice, a law of the speed (``c_h u|u|``), is fitted only where the
#: identification files move in the outer half of the tested stroke, where a stop may
#: engage, at speeds this many times apart (the 90th over the 10th percentile of |ẋ|
#: there).  At one speed it cannot be told from an elastomer's hysteresis, and it
#: extrapolates as the square of the speed: the paper's programme reaches the stroke's
#: ends in its quasi-static test alone (5 mm/s), where on plain stops behind a 150 Hz
#: filter an orifice of 2.7·10⁵ N·s²/m² stood in for 7 N and left the held-out 3 Hz sine
#: at 17.6 kN.
ORIFICE_SPEED_SPAN = 3.0
#: an end stop's progressive force is fitted as the force at this fraction of the tested
#: stroke into the stop and its exponent (``k δⁿ = F_ref (δ/δ_ref)ⁿ``): ``k`` and ``n``
#: alone trade against each other over orders of magnitude
STOP_REFERENCE_FRACTION = 0.1


def _end_stops(s: Scales) -> Candidate:
    """End stops: engagement within the tested stroke (outside it they cannot be seen), a
    progressive force ``F_ref (δ/δ_ref)ⁿ`` of 1 N .. 100 kN at a tenth of the stroke into
    the stop with ``n`` 1 .. 5 (linear to steeply progressive) beside a linear stiffness up
    to that force's scale (an elastomer's first millimetres), an elastomer's hysteresis
    η 0 .. 0.8, a damping growing with the penetration up to what makes the progressive
    force at the files' speeds, a hydraulic stop's orifice damping ``c_h u|u|`` up to
    1 MN at the files' top speed, engaging over 0.05 .. 2 ``δ_ref`` (a start of its own
    form has it on, the others off; held off where the files reach the stroke's ends at
    one speed, :data:`ORIFICE_SPEED_SPAN`), and the compression stop 1/30 .. 30 times
    the rebound stop (a bump stop and a top-out stop are different parts); scales in log
    space, their low ends no force at all within the tested stroke (the linear
    stiffness, the hysteresis and both dampings are optional: held there where the files
    do not determine them).  A stop fitted on top
    of an identification has to undo a gas spring that absorbed it; the
    re-identification leaves out the outer half of the tested stroke, where a stop may
    engage (the quasi-static fit then sees the gas spring alone)."""
    x_lo, x_hi, span = s.x_lo, s.x_hi, s.span
    mid_stroke = 0.5 * (x_lo + x_hi)
    d_ref = STOP_REFERENCE_FRACTION * span

    def outer_half(data: MeasuredData) -> np.ndarray:
        return np.abs(data.displacement - mid_stroke) > OUTER_STROKE_FRACTION * span

    def fields(v: Mapping[str, float]) -> dict[str, float]:
        return {"rebound_position_m": v["rebound_position_m"],
                "compression_position_m": v["compression_position_m"],
                "stiffness_n_m2": v["reference_force_n"] / d_ref ** v["progressive_exponent"],
                "progressive_exponent": v["progressive_exponent"],
                "linear_stiffness_n_m": v["linear_stiffness_n_m"],
                "hysteresis": v["hysteresis"], "damping_n_s_m2": v["damping_n_s_m2"],
                "hydraulic_damping_n_s2_m2": v["hydraulic_damping_n_s2_m2"],
                "hydraulic_engagement_m": v["hydraulic_engagement_m"],
                "compression_scale": v["compression_scale"]}

    # the plain stops' starts: the force of 1e6 N/m² δ² (1e7, 1e4) at δ_ref; and where
    # the identified model's slowest file starts to miss at each end of the stroke
    f6, f7, f4 = (k * d_ref ** 2 for k in (1e6, 1e7, 1e4))
    v_top = max(s.v_max, 1e-3)
    # the hydraulic damping off (its low end) in the starts but the form's own, which
    # has it make the progressive start's force at half the top speed
    d_h = 0.5 * d_ref
    off = (1.0, d_h)
    knees = stroke_knees(s)
    at_knees = (((*knees, f6, 2.0, 1e3, 0.1, 1e3, *off, 1.0),) if knees is not None
                else ())
    stops = Candidate(
        "end_stops",
        (Parameter("rebound_position_m", x_lo + 0.5 * span, x_hi, x_hi - 0.15 * span, False,
                   "m"),
         Parameter("compression_position_m", x_lo, x_hi - 0.5 * span, x_lo + 0.15 * span,
                   False, "m"),
         Parameter("reference_force_n", 1.0, 1e5, f6, True, "N"),
         Parameter("progressive_exponent", 1.0, 5.0, 2.0, False, "-"),
         Parameter("linear_stiffness_n_m", 1.0, 1e5 / d_ref, 1e3, True, "N/m",
                   optional=True),
         Parameter("hysteresis", 0.0, 0.8, 0.1, False, "-", optional=True),
         Parameter("damping_n_s_m2", 1.0, 1e10 / v_top, 1e3, True, "N·s/m²",
                   optional=True),
         Parameter("hydraulic_damping_n_s2_m2", 1.0, 1e6 / v_top ** 2, 1.0, True,
                   "N·s²/m²", optional=True),
         Parameter("hydraulic_engagement_m", 0.05 * d_ref, 2.0 * d_ref, d_h, True, "m",
                   part_of="hydraulic_damping_n_s2_m2"),
         Parameter("compression_scale", 1.0 / 30.0, 30.0, 1.0, True, "-")),
        fields, may_act=outer_half, prefit_keep=2,
        note=f"the progressive force fitted at {1e3 * d_ref:.3g} mm into the stop",
        extra_starts=((x_hi - 0.3 * span, x_lo + 0.3 * span, f6, 2.0, 1e3, 0.1, 1e3, *off,
                       1.0),
                      (x_hi - 0.05 * span, x_lo + 0.05 * span, f7, 3.0, 1e3, 0.1, 1e3,
                       *off, 1.0),
                      (x_hi, x_lo, f4, 2.0, 1.0, 0.0, 1.0, *off, 1.0),  # (almost) not engaged
                      *at_knees),
        # a hydraulic stop: a soft spring and the orifice
        form_starts=((x_hi - 0.15 * span, x_lo + 0.15 * span, f4, 1.0, 1e3, 0.0, 1.0,
                      f6 / (0.5 * v_top) ** 2, d_h, 1.0),))
    speeds = np.concatenate([speed(d)[outer_half(d)] for d in s.fit_data])
    top = float(np.percentile(speeds, 90)) if speeds.size else 0.0
    if speeds.size and top >= ORIFICE_SPEED_SPAN * max(np.percentile(speeds, 10), 1e-12):
        return stops
    # the files reach the stroke's ends at one speed: no orifice, nor its start; past
    # the stops at speeds beyond what they span, the stops' law is not theirs to tell

    def undetermined(data: MeasuredData, v: Mapping[str, float]) -> np.ndarray:
        x = data.displacement
        past = (x > v["rebound_position_m"]) | (x < v["compression_position_m"])
        return past & (speed(data) > ORIFICE_SPEED_SPAN * top)

    return dataclasses.replace(
        stops.holding({"hydraulic_damping_n_s2_m2"}), form_starts=(),
        note=f"{stops.note}; no hydraulic stop's orifice: the files reach the stroke's ends "
             "at one speed, where a law of the speed cannot be told from a hysteresis",
        undetermined=undetermined,
        limit=f"the fit files move in the outer half of the stroke at one speed (90 % of "
              f"their samples there below {1e3 * top:.2g} mm/s): past the stops above "
              f"{1e3 * ORIFICE_SPEED_SPAN * top:.2g} mm/s, the stops' law of the speed is "
              "not theirs to tell")


#: the stroke's knees: the identified model's residual on the slowest file, in this many
#: bins of stroke ...
KNEE_BINS = 40
#: ... misses beyond this multiple of its middle half's median from a bin to the end
KNEE_FACTOR = 3.0


def stroke_knees(s: Scales) -> tuple[float, float] | None:
    """Where the identified model starts to miss towards each end of the stroke on the
    slowest identification file (the quasi-static test: gas spring and friction only,
    where a stop's engagement shows as a knee): the bin of stroke beyond which the median
    of ``|residual|`` stays above :data:`KNEE_FACTOR` × its median over the middle half of
    the stroke, at the rebound end and at the compression end; ``None`` where there is
    none at either end."""
    from damper_emulator.model.compressible import DamperModel, simulate

    slow = min(s.fit_data, key=lambda r: float(np.max(speed(r))))
    try:
        res = simulate(DamperModel(s.cfg), slow.time, slow.displacement, slow.velocity)
    except (ValueError, UserError):
        return None
    r = np.abs(slow.force - res.force_n)
    x = slow.displacement
    edges = np.linspace(float(np.min(x)), float(np.max(x)), KNEE_BINS + 1)
    idx = np.clip(np.searchsorted(edges, x) - 1, 0, KNEE_BINS - 1)
    med = np.array([float(np.median(r[idx == k])) if np.any(idx == k) else 0.0
                    for k in range(KNEE_BINS)])
    quarter = KNEE_BINS // 4
    thr = KNEE_FACTOR * max(float(np.median(med[quarter:KNEE_BINS - quarter])), 1e-9)
    above = med > thr
    top = next((k for k in range(KNEE_BINS // 2, KNEE_BINS) if above[k:].all()), None)
    bottom = next((k for k in range(KNEE_BINS // 2, -1, -1) if above[:k + 1].all()), None)
    if top is None and bottom is None:
        return None
    x_r = float(edges[top]) if top is not None else float(edges[-1])
    x_c = float(edges[bottom + 1]) if bottom is not None else float(edges[0])
    return x_r, x_c


def _air(s: Scales) -> Candidate:
    """Air entrainment: 0.001 % .. 20 % free air at 1 atm."""
    return Candidate(
        "air_entrainment", (Parameter("air_volume_fraction", 1e-5, 0.2, 3e-3, True, "-"),),
        _with({}))


def _groove(s: Scales) -> Candidate:
    """Position-dependent damping: a groove of 0.1 .. 5 mm equivalent diameter anywhere in
    the tested stroke, 1 mm to the whole stroke long.  A groove is seen where the valves
    work hard: within the dynamic test's (narrowest file's) stroke, so more starts lie
    there, a quarter of that stroke long, in each half of it and in its middle."""
    x_lo, x_hi, span = s.x_lo, s.x_hi, s.span
    a_lo, a_hi = math.pi / 4 * 1e-4 ** 2, math.pi / 4 * 5e-3 ** 2
    a_mm = math.pi / 4 * 1e-3 ** 2
    mid = 0.5 * (x_lo + x_hi)
    narrow = min(s.fit_data, key=lambda r: float(np.ptp(r.displacement)))
    n_lo, n_hi = float(np.min(narrow.displacement)), float(np.max(narrow.displacement))
    n_span, n_mid = max(n_hi - n_lo, 1e-3), 0.5 * (n_lo + n_hi)
    narrow_starts = tuple((a_mm, c, 0.25 * n_span) for c in
                          (n_mid - 0.25 * n_span, n_mid, n_mid + 0.25 * n_span))
    return Candidate(
        "bypass_groove",
        (Parameter("area_m2", a_lo, a_hi, a_mm, True, "m²"),
         Parameter("center_m", x_lo, x_hi, mid, False, "m"),
         Parameter("half_length_m", 1e-3, span, 0.25 * span, True, "m")),
        _with({}),
        extra_starts=((a_mm, x_lo + 0.25 * span, 0.1 * span),
                      (a_mm, x_hi - 0.25 * span, 0.1 * span),
                      *narrow_starts,
                      (4.0 * a_lo, mid, 0.25 * span)))  # (almost) closed


def _gas(s: Scales) -> Candidate:
    """Gas spring: thermal time constants from 10 ms (isothermal at every test speed) to
    100 s (adiabatic at all but the quasi-static test).  The quasi-static fit (eq 37)
    assumes the data sheet's γ; a gas that exchanges heat is isothermal over a test that
    slow, so the re-identification fits eq 37 with γ = 1 (and the joint fit starts from
    the gas charge and volume that gives; as a later effect, from those two alone, the
    rest of the present model kept)."""
    return Candidate(
        "gas_heat_transfer",
        (Parameter("thermal_time_constant_s", 0.01, 100.0, 1.0, True, "s"),), _with({}),
        extra_starts=((0.1,),), identify_as=isothermal_gas, identify_keeps=GAS_PARAMETERS)


def _inertia(s: Scales) -> Candidate:
    """Inertia: a mass between the load cell and the damper, from a thousandth of the mass
    whose ``m ẍ`` would be the whole force at the files' largest acceleration to that mass
    (a phase lead, which no other candidate has: a valve lag, a compliance and free air
    lag; 1.5 kg on the sport damper's speed series was taken by a valve lag and a series
    spring together).  It acts on every sample: no re-identification."""
    a_max = max(float(np.percentile(np.abs(np.gradient(np.gradient(r.displacement, r.time),
                                                        r.time)), 99.0))
                for r in s.fit_data)
    f_max = max(float(np.max(np.abs(r.force))) for r in s.fit_data)
    m_scale = f_max / max(a_max, 1e-3)
    return Candidate(
        "inertia", (Parameter("mass_kg", 1e-3 * m_scale, m_scale, 1e-2 * m_scale, True,
                              "kg"),), _with({}), extra_starts=((1e-3 * m_scale,),))


#: the library's candidates, one builder per family, in library order (a builder gives
#: ``None`` where its effect cannot be told from these files)
BUILDERS: tuple[Callable[[Scales], Candidate | None], ...] = (
    _friction, _thermal, _cavitation, _valve_lag, _compliance, _end_stops, _air, _groove,
    _gas, _inertia)
#: the effects the library holds, in its order
LIBRARY = ("lugre_friction", "viscosity_temperature", "cavitation", "valve_lag",
           "series_compliance", "end_stops", "air_entrainment", "bypass_groove",
           "gas_heat_transfer", "inertia")


def candidates(cfg: ModelConfig, fit_data: Sequence[MeasuredData],
               effects: Sequence[str] | None = None) -> list[Candidate]:
    """The candidate effects for a base model ``cfg`` identified on ``fit_data`` (only
    ``effects`` when given, in library order; each builder states its bounds and starts
    with their reasons)."""
    if effects is not None:
        unknown = [e for e in effects if e not in LIBRARY]
        if unknown:
            raise UserError(f"unknown effect {unknown[0]!r} (one of {', '.join(LIBRARY)})")
    scales = Scales(cfg, fit_data)
    out = [c for build in BUILDERS if (c := build(scales)) is not None]
    return [c for c in out if effects is None or c.effect in effects]
