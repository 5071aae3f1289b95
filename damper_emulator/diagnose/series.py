"""What moves from file to file over a test series: the rig's zero and gain, the damper's
gas charge, friction and oil.

A test series is recorded file after file.  Over it the load cell's zero drifts (it moves
the whole force, at rest too, and moves on within a file with time), a gain may change, the
gas charge leaks (the static force ``A_rod p_gas`` falls, and with it the gas spring's
stroke dependence, eq 3), the seal's friction changes, the oil warms (its viscosity falls,
and the valves' pressure drop with ``ν^¼``, eqs 8–9).  The paper's model has one value of
each for the whole series: a diagnosis that does not look for what moves names an effect of
the damper for it, or leaves it in the held-out residual.

**The hypotheses** (:data:`KINDS`), each a set of columns per file (:func:`file_columns`),
fitted per file by least squares on the model's residual ``F_meas − F_model``:

=================  ==============================================  ======  ==========
kind               columns (per file)                              cause   names
=================  ==============================================  ======  ==========
``zero``           1 (the offset), ``t − t̄`` (its drift in time¹)   rig     —
``gain``           ``F_model``                                     rig     —
``gas``            ``∂F/∂p_gas``                                    damper  gas_spring
``friction``       ``∂F/∂F_friction``                               damper  friction
``valve_scale``    ``∂F/∂s``, the valves' Δp scaled by ``s``        damper  thermal
=================  ==============================================  ======  ==========

¹ In files whose excitation is stationary in time (:func:`stationary`): not in a chirp,
whose speed, and the model's error with it, grows with time.

The first file of the series is the reference (the rig was zeroed and calibrated before
it, the model's parameters are its): it has no column but the zero's drift in time.  The
derivatives are forward differences of the model simulated over the file (a step of
:data:`SENSITIVITY_STEP` of the value).  The gas force is linear in ``p_gas`` (eq 3) and
the friction's in its level.  The oil's temperature acts as the library's thermal
extension has it act: the whole valve characteristic scaled by ``s = (ν/ν_ref)^¼``
(:mod:`damper_emulator.model.extensions`; the extension itself makes the column, at a
typical oil's β).  Where the force is not linear in a damper's parameter (a valve scale of
0.8), each file's column is then the secant to the value fitted there
(:func:`refined`, :data:`SECANT_PASSES` times): one column per file still, exact at the
fitted value.

**Forward selection** (:func:`select`), on every file of the series: the held-out files
are part of the series, and what is fitted per file is the rig's or the file's state (as
a temperature column is), never the damper's parameters, which only the identification
files fit.  A hypothesis is significant on top of those already taken when

* it lowers the effective BIC (each file's samples reduced to the effective number of an
  AR(1) residual, ``joint.delta_bic``) by at least 10 for its columns,
* what it fits moves one file's force by at least :data:`MIN_NOISE_FRACTION` of its noise,
* the first one taken explains at least :data:`MIN_SERIES_EXPLAINED` of the series'
  structured residual (each file's mean square above its noise's) where it acts, each
  file weighted by how much it moves it (:func:`explained_where_it_acts`): a per-file
  column also takes a share of an effect the model lacks (a per-file friction or gain
  took half of a 6 kg mass's residual, its values four to seven times the seal's), and
  the library's rounds are the place for that;
* a gain follows the series or is one of the whole series (its values within
  :data:`GAIN_SPREAD`), and a damper's parameter follows the series: its per-file values
  lie on a line over the files' places in the series (where the series' order is the
  files' speeds, :func:`speed_ordered`, a friction and a valve scale are not tried and a
  gain must be one of the series: a change over such a series is a change with the
  speed as much) (R² ≥ :data:`MIN_TREND_R2`, the slope beyond
  :data:`MIN_TREND_T` σ, at least :data:`MIN_TREND_FILES` files).  A gas that leaks or an
  oil that warms moves one way; a per-file value that jumps about is the model's own
  error at that file's speeds, which a per-file scale of the damping would otherwise take.

The significant hypothesis with the lowest ΔBIC is taken.  Where the first round's best
fails only the explained structure, the identification may have absorbed it (the
identified valves take each file's offset where the dynamic tests are many files): the
diagnosis refits the paper's model twice, with that kind per file and without it, and
takes the kind where it explains :data:`MIN_SERIES_EXPLAINED` of what the refit without it
leaves, with a ΔBIC of at most −10 (``selection.follow_series``, :func:`contender`,
:func:`refit_evidence`); the series is then weighed again on the model refitted with it.

**Rig or damper.**  A zero offset and a gas charge both move the static force; the gas
also moves the gas spring's stroke dependence, weakly (``γ A_rod x / V``: ±10 % over a
quasi-static test's ±75 mm on the sport damper), and a load cell's zero also drifts
within a file, which a gas charge does not (the zero's drift columns cost the zero's BIC
where there is none).  So the two are weighed by their BIC, and one of them at most is
taken (:data:`EXCLUSIVE`).  Where their BICs lie within :data:`RIG_OR_DAMPER_BIC` of each
other the data do not tell them apart: the gas is named where it follows the series, the
zero otherwise, and the finding says that the other fits nearly as well.  A gain and a
valve scale are told apart by the static force, which a gain scales and a valve scale does
not.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.base import PerFile, Record, config_value, config_with
from damper_emulator.diagnose.statistics import delta_bic, fit_columns, lag1
from damper_emulator.model.compressible import DamperModel

__all__ = [
    "EXCLUSIVE",
    "KINDS",
    "Drift",
    "FileColumns",
    "Kind",
    "Line",
    "SeriesResult",
    "alone",
    "contender",
    "explained_where_it_acts",
    "file_columns",
    "refined",
    "refit_evidence",
    "select",
    "series_positions",
    "speed_ordered",
    "trend",
]

#: relative step of the damper parameters' forward differences
SENSITIVITY_STEP = 0.01
#: a hypothesis lowers the effective BIC by at least this much ...
SERIES_MAX_DELTA_BIC = -10.0
#: ... moves one file's force by at least this fraction of its noise level (r.m.s. of
#: what it fits there: significant but smaller, it is nothing a user sees) ...
MIN_NOISE_FRACTION = 0.5
#: ... and the first one taken explains at least this fraction of the series' structured
#: residual where it acts (:func:`explained_where_it_acts`): as the library's effects must
#: of the held-out residual's structured power (``outcome.MIN_EXPLAINED``), or the answer
#: is ``other``
MIN_SERIES_EXPLAINED = 0.75
#: a damper parameter's per-file values follow the series: R² of their line at least ...
MIN_TREND_R2 = 0.75
#: ... its slope this many σ from zero ...
MIN_TREND_T = 3.0
#: ... over at least this many files
MIN_TREND_FILES = 3
#: a zero and a gas charge whose BICs differ by less than this are not told apart by their
#: fits (Kass & Raftery: 6–10 is "strong" evidence, beyond 10 "very strong")
RIG_OR_DAMPER_BIC = 10.0
#: most hypotheses taken
MAX_KINDS = 3
#: a gain of the whole series: its per-file values lie within this of each other (a load
#: cell's gain does not jump from file to file; a per-file gain that does takes a share of
#: an effect the model lacks: 1.03–1.08 over four files of a 6 kg mass)
GAIN_SPREAD = 0.01
#: the zero's drift in time is fitted in files whose speed correlates with time less
#: than this (:func:`stationary`): a quasi-static triangle, a sine, a random road; not a
#: chirp, whose speed grows over it
STATIONARY_CORRELATION = 0.3
#: secant passes of a damper parameter's per-file column (:func:`refined`)
SECANT_PASSES = 2


@dataclass(frozen=True)
class Kind:
    """A quantity that may move from file to file."""

    name: str
    #: what is reported per file, and its unit
    parameter: str
    unit: str
    #: ``rig`` or ``damper``
    cause: str
    #: the damper family it names (``None``: the rig's)
    family: str | None
    doc: str
    #: the damper parameter stepped for its column (``None``: a column of its own)
    path: str | None = None
    #: further columns (fitted with the kind, in every file, the reference's too)
    extra: tuple[str, ...] = ()

    @property
    def columns(self) -> tuple[str, ...]:
        return (self.name, *self.extra)


KINDS: tuple[Kind, ...] = (
    Kind("zero", "force_offset_n", "N", "rig", None,
         "the load cell's zero (its offset against the series' first file, and its drift "
         "within each file)", extra=("zero_drift",)),
    Kind("gain", "force_gain", "-", "rig", None,
         "the force channel's gain per file against the model's pressures (the first "
         "file's static force, gas and friction, takes any gain; the dynamic files' is "
         "told by the oil's compressibility, α from the data sheet)"),
    Kind("gas", "gas_pressure_static_pa", "Pa", "damper", "gas_spring",
         "the gas charge P_gas,static (eq 3)", path="gas_pressure_static_pa"),
    Kind("friction", "friction_force_n", "N", "damper", "friction",
         "the seal friction (eq 4)", path="friction_force_n"),
    Kind("valve_scale", "valve_pressure_scale", "-", "damper", "thermal",
         "the valves' pressure drop against the first file's, (ν/ν_ref)^¼: the oil's "
         "temperature (eqs 8–9)"),
)
KIND_BY_NAME = {k.name: k for k in KINDS}
#: kinds whose columns are nearly the same (a zero offset and a gas charge both move the
#: static force; a gain and a valve scale both the damping): one of each pair at most
EXCLUSIVE = (frozenset({"zero", "gas"}), frozenset({"gain", "valve_scale"}))
#: the temperature [°C] the valve-scale column is simulated at (any: only the
#: difference to the reference temperature matters)
SCALE_TEMPERATURE_C = 25.0


@dataclass
class FileColumns:
    """One file of the series: the model's residual and force over the samples that
    count, and each column (absent where the file has none, e.g. the reference's
    offset)."""

    name: str
    held_out: bool
    residual: np.ndarray
    force: np.ndarray
    time: np.ndarray
    columns: dict[str, np.ndarray]
    #: the file's noise level [N] (the cost's weight)
    sigma: float


def series_positions(records: Sequence[Record], order: Sequence[str] | None = None
                     ) -> dict[str, float]:
    """Each file's place in the series, by name: its start [s] on a common clock where
    the files' time columns are one (each file starts after the one before it ends, in
    the given order), else its index in ``order`` (default: the records' order)."""
    names = list(order) if order is not None else [r.name for r in records]
    by_name = {r.name: r for r in records}
    starts = [float(by_name[n].data.time[0]) for n in names]
    ends = [float(by_name[n].data.time[-1]) for n in names]
    if (len(names) > 1 and all(starts[k + 1] >= ends[k] for k in range(len(names) - 1))
            and ends[0] > starts[0]):
        return dict(zip(names, starts))
    return {n: float(k) for k, n in enumerate(names)}


def stationary(t: np.ndarray, v: np.ndarray) -> bool:
    """Whether a file's excitation is stationary in time: its speed does not grow or fall
    over the file (``|corr(t, |v|)|`` below :data:`STATIONARY_CORRELATION`).  Only there is
    a drift in time the zero's: in a chirp, time is the sweep's frequency and speed, and a
    model error that grows with the speed grows with time too (it took a leaking gas's
    comparison from the zero's offsets)."""
    speed = np.abs(v)
    if t.size < 3 or np.ptp(speed) == 0.0:
        return True
    return abs(float(np.corrcoef(t, speed)[0, 1])) < STATIONARY_CORRELATION


def _stepped(model: DamperModel, kind: Kind, value: float) -> DamperModel:
    """``model`` with ``kind``'s parameter at ``value`` (the valve scale: its valves'
    pressure drop scaled by ``value``, the library's thermal extension at a typical oil's
    β, its reference temperature set so that ``exp(−β (T − T_ref)/4) = value`` at
    :data:`SCALE_TEMPERATURE_C`)."""
    if kind.path is not None:
        return DamperModel(config_with(model.cfg, {kind.path: value}))
    from damper_emulator.diagnose.candidates import TYPICAL_VISCOSITY_COEFFICIENT_PER_K
    from damper_emulator.params import ExtensionParams, ViscosityTemperatureParams

    beta = TYPICAL_VISCOSITY_COEFFICIENT_PER_K
    t_ref = SCALE_TEMPERATURE_C + 4.0 * math.log(value) / beta
    return model.with_extensions(ExtensionParams(
        viscosity_temperature=ViscosityTemperatureParams(beta, t_ref)))


def reference_value(model: DamperModel, kind: Kind) -> float:
    """The model's value of a damper ``kind``'s parameter (the valve scale: 1)."""
    return config_value(model.cfg, kind.path) if kind.path is not None else 1.0


def _simulated(rec: Record, model: DamperModel, kind: Kind, rig: RigParams | None
               ) -> np.ndarray:
    """``model``'s force on ``rec`` as recorded, the samples that count (the valve
    scale's at the constant temperature its column is made at)."""
    if kind.name == "valve_scale":
        rec = dataclasses.replace(rec, data=dataclasses.replace(
            rec.data, temperature=np.full_like(rec.data.time, SCALE_TEMPERATURE_C)))
    return rec.simulate(model, fast=True, rig=rig)[rec.start:]


def file_columns(model: DamperModel, rig: RigParams | None, records: Sequence[Record],
                 reference: str, sigmas: Mapping[str, float]) -> list[FileColumns]:
    """Every file's residual, force and columns at ``model`` (through ``rig``, the
    estimated chain, where a file carries none); ``reference`` is the series' first
    file."""
    damper = [k for k in KINDS if k.cause == "damper"]
    stepped = {k.name: (reference_value(model, k),
                        _stepped(model, k, reference_value(model, k)
                                 * (1.0 + SENSITIVITY_STEP))) for k in damper}
    out = []
    for rec in records:
        k = rec.start
        counted = rec.simulate(model, fast=True, rig=rig)[k:]
        t = rec.data.time[k:]
        cols: dict[str, np.ndarray] = {}
        if stationary(t, rec.velocity[k:]):
            cols["zero_drift"] = t - t.mean()
        if rec.name != reference:
            cols["zero"] = np.ones_like(t)
            cols["gain"] = counted
            for kind in damper:
                v, m = stepped[kind.name]
                at_ref = (counted if kind.name != "valve_scale"
                          else _simulated(rec, _stepped(model, kind, 1.0), kind, rig))
                cols[kind.name] = ((_simulated(rec, m, kind, rig) - at_ref)
                                   / (v * SENSITIVITY_STEP))
        out.append(FileColumns(rec.name, rec.held_out, rec.data.force[k:] - counted,
                               counted, t, cols, max(sigmas.get(rec.name, 0.0), 1e-9)))
    return out


class Line(NamedTuple):
    """A weighted straight line: its slope and the slope's σ, R², and the weighted mean
    point it passes through."""

    slope: float
    slope_std: float
    r2: float
    x0: float = 0.0
    y0: float = 0.0


#: no line (fewer than two determined values)
NO_LINE = Line(0.0, math.inf, 0.0)


@dataclass
class Drift:
    """A kind taken: its per-file coefficients (the parameter's change, the offset, the
    gain less one) with their 1σ, how they follow the series, and for the zero its drift
    within each file."""

    kind: Kind
    per_file: dict[str, float]
    std: dict[str, float]
    #: the change over the series per unit of place (per file, or per second on a common
    #: clock), its σ, and the R² of the per-file values' line
    slope: float = 0.0
    slope_std: float = math.inf
    r2: float = 0.0
    delta_bic: float = 0.0
    gain: float = 0.0
    explained: float = 0.0
    #: the zero's drift within each file [N/s] and its σ
    rates: dict[str, float] = field(default_factory=dict)
    rates_std: dict[str, float] = field(default_factory=dict)
    #: the other of an exclusive pair that fits nearly as well (rig or damper not told
    #: apart), if any
    ambiguous_with: str | None = None
    #: a damper parameter's value in the reference file (the model's)
    reference_value: float | None = None
    #: the per-file values' line (of the coefficients: the values less the reference)
    line: Line = NO_LINE

    def values(self) -> dict[str, float]:
        """The per-file values in the parameter's unit: the model's value plus the
        change for a damper parameter, 1 plus the coefficient for a gain, the offset as
        fitted for the zero."""
        if self.kind.name == "gain":
            return {k: 1.0 + v for k, v in self.per_file.items()}
        base = self.reference_value or 0.0
        return {k: base + v for k, v in self.per_file.items()}

    def reference_level(self) -> float:
        """The reference file's value: the model's for a damper parameter, 1 for a gain,
        no offset for the zero."""
        if self.kind.name == "gain":
            return 1.0
        return self.reference_value or 0.0

    def to_json(self, reference: str | None = None) -> dict[str, Any]:
        """The JSON's ``drift`` entry; ``per_file`` with the ``reference`` file first (at
        :meth:`reference_level`) where named."""
        def finite(d: Mapping[str, float]) -> dict[str, float | None]:
            return {k: (v if math.isfinite(v) else None) for k, v in d.items()}

        per_file = ({reference: self.reference_level()} if reference is not None
                    and reference not in self.per_file else {})
        per_file.update(self.values())
        doc = {"parameter": self.kind.parameter, "unit": self.kind.unit,
               "kind": self.kind.name, "cause": self.kind.cause,
               "family": self.kind.family, "per_file": per_file,
               "reference_file": reference,
               "std": finite(self.std), "reference_value": self.reference_value,
               "trend": {"slope": self.slope,
                         "slope_std": self.slope_std if math.isfinite(self.slope_std)
                         else None, "r2": self.r2},
               "delta_bic": self.delta_bic, "gain": self.gain,
               "explained": self.explained, "ambiguous_with": self.ambiguous_with}
        if self.rates:
            doc["drift_within_file_n_per_s"] = dict(self.rates)
            doc["drift_within_file_std"] = finite(self.rates_std)
        return doc


@dataclass
class SeriesResult:
    """What :func:`select` took, and every hypothesis it weighed (for the report)."""

    taken: list[Drift]
    tried: list[dict[str, Any]]
    positions: dict[str, float]

    @property
    def reference(self) -> str | None:
        """The series' first file (the reference of every kind)."""
        return min(self.positions, key=lambda n: self.positions[n]) if self.positions else None

    def per_file(self, files: Sequence[FileColumns]) -> dict[str, PerFile]:
        """What the fits take per file for the kinds taken (:class:`PerFile`)."""
        out = {}
        names = [c for d in self.taken for c in d.kind.columns]
        for fc in files:
            fixed = [fc.columns[n] for n in names if n != "gain" and n in fc.columns]
            gain = "gain" in names and "gain" in fc.columns
            if fixed or gain:
                cols = (np.column_stack(fixed) if fixed
                        else np.zeros((fc.residual.size, 0)))
                have = tuple(n for n in names if n != "gain" and n in fc.columns)
                out[fc.name] = PerFile(cols, gain, have + (("gain",) if gain else ()))
        return out

    def refresh(self, records: Sequence[Record], model: DamperModel,
                rig: RigParams | None) -> None:
        """Every kind's per-file values fitted again on ``model``'s residual (the model
        after the diagnosis, through ``rig``): what the fits took per file, at the end."""
        coefs: list[dict[str, tuple[float, float]]] = []
        files = []
        for rec in records:
            k = rec.start
            force = rec.simulate(model, rig=rig)[k:]
            got: dict[str, tuple[float, float]] = {}
            if rec.per_file is not None:
                a = rec.per_file.design(force)
                c, sd, _ = fit_columns(a, rec.data.force[k:] - force)
                got = {n: (float(c[i]), float(sd[i]))
                       for i, n in enumerate(rec.per_file.names)}
            coefs.append(got)
            files.append(FileColumns(rec.name, rec.held_out, np.zeros(0), force,
                                     rec.data.time[k:], {}, 1.0))
        for d in self.taken:
            new = _drift(d.kind, files, coefs, self.positions, model)
            d.reference_value = new.reference_value
            d.per_file, d.std, d.rates, d.rates_std = (new.per_file, new.std, new.rates,
                                                       new.rates_std)
            d.slope, d.slope_std, d.r2, d.line = new.slope, new.slope_std, new.r2, new.line


def _fit(files: Sequence[FileColumns], names: Sequence[str]
         ) -> tuple[list[np.ndarray], list[dict[str, tuple[float, float]]]]:
    """Per file, the residual less its fit on the columns ``names`` it has, and each
    column's coefficient with its 1σ (AR(1)-inflated)."""
    res: list[np.ndarray] = []
    coefs: list[dict[str, tuple[float, float]]] = []
    for fc in files:
        have = [n for n in names if n in fc.columns]
        if not have:
            res.append(fc.residual)
            coefs.append({})
            continue
        c, sd, r = fit_columns(np.column_stack([fc.columns[n] for n in have]), fc.residual)
        res.append(r)
        coefs.append({n: (float(c[i]), float(sd[i])) for i, n in enumerate(have)})
    return res, coefs


def _cost(files: Sequence[FileColumns], res: Sequence[np.ndarray]) -> float:
    """``Σ_f mean(r_f²)/σ_f²``: every file in units of its own noise."""
    return sum(float(np.mean(r * r)) / fc.sigma ** 2 for fc, r in zip(files, res))


def explained_where_it_acts(sigmas: Sequence[float], before: Sequence[np.ndarray],
                            after: Sequence[np.ndarray]) -> float:
    """The fraction of the structured residual (each file's mean square above its noise
    level's square, in units of that square) that a change from ``before`` to ``after``
    removes, each file weighted by how much the change moves it there (the mean square of
    ``before − after``): what a kind explains where it acts.  A per-file column that takes
    a share of an effect the model lacks explains a share of each file it moves (half of
    a 6 kg mass's residual), a drift of the rig or the damper nearly all of it, also where
    the model's own form error dominates other files (a van's chirp beside a drifting
    zero)."""
    num = den = 0.0
    for sg, r0, r1 in zip(sigmas, before, after):
        if r0.size == 0:
            continue
        s0 = max(float(np.mean(r0 * r0)) / sg ** 2 - 1.0, 0.0)
        if s0 <= 0.0:
            continue
        s1 = max(float(np.mean(r1 * r1)) / sg ** 2 - 1.0, 0.0)
        moved = float(np.mean((r0 - r1) ** 2)) / sg ** 2
        num += moved * (1.0 - min(s1 / s0, 1.0))
        den += moved
    return num / den if den > 0 else 0.0


def _material(files: Sequence[FileColumns], before: Sequence[np.ndarray],
              after: Sequence[np.ndarray]) -> float:
    """The largest r.m.s. of what a kind fitted, over the files, in units of the file's
    noise level."""
    return max((float(np.sqrt(np.mean((b - a) ** 2))) / fc.sigma
                for fc, b, a in zip(files, before, after)), default=0.0)


def trend(positions: Sequence[float], values: Sequence[float], std: Sequence[float]
          ) -> Line:
    """The weighted straight line through ``values`` (1σ ``std``) over ``positions``; the
    slope's σ from the values' own, inflated where they scatter beyond them."""
    x, y = np.asarray(positions, float), np.asarray(values, float)
    s = np.asarray(std, float)
    w = np.where(np.isfinite(s) & (s > 0), 1.0 / np.where(s > 0, s, 1.0) ** 2, 0.0)
    if np.count_nonzero(w) < 2 or np.ptp(x[w > 0]) == 0.0:
        return NO_LINE
    xm, ym = np.average(x, weights=w), np.average(y, weights=w)
    sxx = float(np.sum(w * (x - xm) ** 2))
    slope = float(np.sum(w * (x - xm) * (y - ym)) / sxx)
    ss_res = float(np.sum(w * (y - ym - slope * (x - xm)) ** 2))
    ss_tot = float(np.sum(w * (y - ym) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 0.0
    chi2 = ss_res / max(int(np.count_nonzero(w)) - 2, 1)
    return Line(slope, math.sqrt(max(chi2, 1.0) / sxx), r2, float(xm), float(ym))


def _drift(kind: Kind, files: Sequence[FileColumns],
           coefs: Sequence[Mapping[str, tuple[float, float]]],
           positions: Mapping[str, float], model: DamperModel | None) -> Drift:
    """The kind's per-file values and their trend over the series.  The rig's reference
    file is at no change by definition (weighted as the best determined file); a damper
    parameter's is the model's, which every identification file set, not it alone: its
    trend is over the files that have a value."""
    per = {fc.name: c[kind.name][0] for fc, c in zip(files, coefs) if kind.name in c}
    sd = {fc.name: c[kind.name][1] for fc, c in zip(files, coefs) if kind.name in c}
    best = min((v for v in sd.values() if v > 0), default=math.inf)
    on_line = [fc for fc in files if fc.name in per or kind.cause == "rig"]
    pos = [positions[fc.name] for fc in on_line]
    vals = [per.get(fc.name, 0.0) for fc in on_line]
    sds = [sd.get(fc.name, best) for fc in on_line]
    line = trend(pos, vals, sds)
    out = Drift(kind, per, sd, line.slope, line.slope_std, line.r2, line=line,
                reference_value=(reference_value(model, kind)
                                 if model is not None and kind.cause == "damper" else None))
    if "zero_drift" in kind.columns:
        out.rates = {fc.name: c["zero_drift"][0] for fc, c in zip(files, coefs)
                     if "zero_drift" in c}
        out.rates_std = {fc.name: c["zero_drift"][1] for fc, c in zip(files, coefs)
                         if "zero_drift" in c}
    return out


def follows_series(d: Drift, n_files: int) -> bool:
    """Whether a damper parameter's per-file values follow the series (module
    docstring)."""
    return (n_files >= MIN_TREND_FILES and d.r2 >= MIN_TREND_R2
            and abs(d.slope) >= MIN_TREND_T * d.slope_std)


def consistent(d: Drift, n_files: int, speed_ordered: bool = False) -> bool:
    """Whether a kind's per-file values are what its cause can do: a damper's parameter
    follows the series; a gain follows it too (an amplifier warming up; not where the
    series' order is its speeds', :func:`speed_ordered`) or is one gain of the whole series
    (its values within :data:`GAIN_SPREAD` of each other); a zero may move as it likes (a
    load cell zeroed again between files)."""
    if d.kind.cause == "damper":
        return follows_series(d, n_files)
    if d.kind.name == "gain":
        values = list(d.values().values())
        return ((follows_series(d, n_files) and not speed_ordered)
                or (bool(values) and max(values) - min(values) <= GAIN_SPREAD))
    return True


#: the files' order over the series follows their speeds when the rank correlation of
#: their places and their speeds (each file's 99th percentile of |ẋ|) is at least this
SPEED_ORDER_CORRELATION = 0.8
#: the kinds whose change over such a series cannot be told from a change with the speed
SPEED_CONFOUNDED = ("friction", "valve_scale")


def speed_ordered(records: Sequence[Record], positions: Mapping[str, float]) -> bool:
    """Whether the series' order follows the files' speeds (a peak-velocity series run
    slowest first): then what changes over the series and what changes with the speed are
    one, and a friction or a valve scale that grows file by file is as much the damper's
    speed dependence as a drift (a 5 % gain on a van's speed series came back as a
    friction growing file by file)."""
    from scipy.stats import spearmanr

    if len(records) < MIN_TREND_FILES:
        return False
    speeds = [float(np.percentile(np.abs(r.velocity), 99.0)) for r in records]
    places = [positions[r.name] for r in records]
    rho = spearmanr(places, speeds).statistic
    return bool(np.isfinite(rho) and rho >= SPEED_ORDER_CORRELATION)


def select(files: Sequence[FileColumns], positions: Mapping[str, float],
           kinds: Sequence[str] | None = None, model: DamperModel | None = None,
           first: str | None = None, evidence: tuple[float, float] = (0.0, 0.0),
           by_speed: bool = False) -> SeriesResult:
    """Forward selection of what moves over the series (module docstring): each round,
    every kind not yet taken (nor excluded by one taken, :data:`EXCLUSIVE`) is fitted
    with those taken; the significant one with the lowest ΔBIC is taken.  ``model``: the
    model the columns were made at (its parameters' values, for the report).  ``first``:
    a kind already shown to move (:func:`refit_evidence`), taken first without the
    explained structure's test (at a model refitted with it, it explains all), with
    ``evidence``, its ``(ΔBIC, explained)`` of that test.  ``by_speed``: the series' order
    follows the files' speeds (:func:`speed_ordered`)."""
    allowed = [KIND_BY_NAME[k] for k in (kinds or [k.name for k in KINDS])]
    taken: list[Drift] = []
    tried: list[dict[str, Any]] = []
    while len(taken) < MAX_KINDS:
        if first is not None and not taken:
            res, coefs = _fit(files, KIND_BY_NAME[first].columns)
            d = _drift(KIND_BY_NAME[first], files, coefs, positions, model)
            d.delta_bic, d.explained = evidence
            taken.append(d)
            continue
        names = [c for d in taken for c in d.kind.columns]
        excluded = {k for pair in EXCLUSIVE if pair & {d.kind.name for d in taken}
                    for k in pair}
        cur_res, _ = _fit(files, names)
        cost0 = _cost(files, cur_res)
        sigmas = [fc.sigma for fc in files]
        scored: dict[str, tuple[Drift, bool]] = {}
        for kind in allowed:
            if kind.name in excluded or any(d.kind is kind for d in taken):
                continue
            k = sum(c in fc.columns for fc in files for c in kind.columns)
            if k == 0:
                continue
            res, coefs = _fit(files, [*names, *kind.columns])
            d = _drift(kind, files, coefs, positions, model)
            d.delta_bic = delta_bic(((r.size, lag1(r), float(np.mean(r * r)),
                                      float(np.mean(r0 * r0)))
                                     for r, r0 in zip(res, cur_res)), k)
            d.gain = 1.0 - math.sqrt(_cost(files, res) / cost0) if cost0 > 0 else 0.0
            d.explained = explained_where_it_acts(sigmas, cur_res, res)
            size = _material(files, cur_res, res)
            ok = (d.delta_bic <= SERIES_MAX_DELTA_BIC and size >= MIN_NOISE_FRACTION
                  and (bool(taken) or d.explained >= MIN_SERIES_EXPLAINED))
            follows = consistent(d, len(files), by_speed)
            tried.append({"round": len(taken) + 1, "kind": kind.name,
                          "parameter": kind.parameter, "delta_bic": d.delta_bic,
                          "gain": d.gain, "explained": d.explained,
                          "size_in_noise": size, "trend_r2": d.r2,
                          "consistent": follows, "significant": ok and follows,
                          "all_but_explained": (d.delta_bic <= SERIES_MAX_DELTA_BIC
                                                and size >= MIN_NOISE_FRACTION
                                                and follows)})
            scored[kind.name] = (d, ok and follows)
        sig = [d for d, ok in scored.values() if ok]
        if not sig:
            break
        taken.append(_rig_or_damper(min(sig, key=lambda d: d.delta_bic), scored))
    return SeriesResult(taken, tried, dict(positions))


def contender(result: SeriesResult) -> str | None:
    """The kind of the first round that passed every test but the explained structure
    (the lowest ΔBIC), where none was taken: what moves over the series may have been
    absorbed by the identification itself (a zero drifting over a peak-velocity series:
    the identified valves took the files' offsets, and the zero explained 47 % of what
    was left), which a refit of the paper's model with it per file tells."""
    if result.taken:
        return None
    first = [t for t in result.tried if t["round"] == 1 and t["all_but_explained"]]
    return min(first, key=lambda t: t["delta_bic"])["kind"] if first else None


def refit_evidence(sigmas: Sequence[float], without: Sequence[np.ndarray],
                   with_kind: Sequence[np.ndarray], k: int) -> tuple[float, float]:
    """``(ΔBIC, explained)`` of the paper's model refitted with a kind per file
    (residuals ``with_kind``, the kind projected out) against the same refit without it
    (``without``), over every file of the series (each in units of its noise level
    ``sigmas``); ``k`` the kind's columns.  Both models are fitted to the identification
    files alike: a kind that only takes what the refit's own parameters would (a gain the
    valves scale away, a friction the series' speeds order) explains little of what the
    refit without it leaves."""
    dbic = delta_bic(((r.size, lag1(r), float(np.mean(r * r)), float(np.mean(r0 * r0)))
                      for r, r0 in zip(with_kind, without)), k)
    return dbic, explained_where_it_acts(sigmas, without, with_kind)


def alone(kind: str, files: Sequence[FileColumns]) -> dict[str, PerFile]:
    """What the fits take per file for ``kind`` alone."""
    return SeriesResult([Drift(KIND_BY_NAME[kind], {}, {})], [], {}).per_file(files)


def _rig_or_damper(best: Drift, scored: Mapping[str, tuple[Drift, bool]]) -> Drift:
    """Between a zero and a gas charge whose BICs lie within :data:`RIG_OR_DAMPER_BIC`
    (module docstring): the gas where it follows the series, else the zero; the other
    noted."""
    if best.kind.name not in ("zero", "gas"):
        return best
    other_name = "gas" if best.kind.name == "zero" else "zero"
    if other_name not in scored:
        return best
    other = scored[other_name][0]
    if abs(other.delta_bic - best.delta_bic) >= RIG_OR_DAMPER_BIC:
        return best
    gas, gas_ok = scored["gas"]
    chosen = gas if gas_ok else scored["zero"][0]
    return dataclasses.replace(chosen, ambiguous_with=(other if chosen is best
                                                       else best).kind.name)


def refined(model: DamperModel, rig: RigParams | None, records: Sequence[Record],
            files: list[FileColumns], result: SeriesResult) -> None:
    """Each damper kind taken: every file's column replaced by the secant from the
    model's value to the value fitted there (:data:`SECANT_PASSES` times, the values
    refitted each time): exact at the fitted value where the force is not linear in the
    parameter.  ``files`` and the kinds' per-file values change in place."""
    by_name = {r.name: r for r in records}
    for d in result.taken:
        kind = d.kind
        if kind.cause != "damper":
            continue
        v0 = reference_value(model, kind)
        at_ref = {}
        for _ in range(SECANT_PASSES):
            for fc in files:
                delta = d.per_file.get(fc.name)
                if delta is None or abs(delta) <= SENSITIVITY_STEP * abs(v0):
                    continue
                rec = by_name[fc.name]
                if fc.name not in at_ref:
                    at_ref[fc.name] = (fc.force if kind.name != "valve_scale" else
                                       _simulated(rec, _stepped(model, kind, 1.0), kind, rig))
                try:
                    moved = _simulated(rec, _stepped(model, kind, v0 + delta), kind, rig)
                except ValueError:  # a value the model refuses: the tangent stays
                    continue
                fc.columns[kind.name] = (moved - at_ref[fc.name]) / delta
            names = [c for t in result.taken for c in t.kind.columns]
            _, coefs = _fit(files, names)
            new = _drift(kind, files, coefs, result.positions, model)
            d.per_file, d.std = new.per_file, new.std
            d.slope, d.slope_std, d.r2, d.line = new.slope, new.slope_std, new.r2, new.line
