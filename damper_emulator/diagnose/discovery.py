"""Term discovery: what a diagnosis leaves, regressed on a dictionary of physical features
of the measured motion and of the model's own states, with sparse regression and
stability selection; the term read as an expression with units and a family hint.

Procedure (:func:`discover`), after the library's rounds (:func:`~damper_emulator.
diagnose.selection.diagnose`):

1. **Gate.**  Only where structure remains: the final model's held-out residual above the
   floor and above :data:`~damper_emulator.diagnose.outcome.STRUCTURE_RATIO` × its
   noise level.  An effect the library found and explained leaves nothing to discover.
2. **Dictionary** (:func:`features`): per sample of every file, each feature of
   :data:`FEATURES` (acceleration; velocity, its powers and its smooth sign; stroke and its
   powers; products; Gaussian position profiles times velocity; temperature and the
   energy dissipated so far, times the model's force; first-order lags of the model's
   force; the compression chamber's (gas) pressure and the pressure drop across the
   piston, times the smooth sign of velocity).  Each column passes through the same
   measurement chain as the model's force (given, or estimated): the term is a force of
   the damper, recorded as the rest of it.
3. **Stability selection** (Meinshausen & Bühlmann 2010) on the identification files:
   :data:`SUBSAMPLES` random halves of the records' :data:`BLOCK_S` blocks (blocks, not
   samples: a dyno residual is correlated over milliseconds), each regressed by
   orthogonal matching pursuit (scikit-learn) with at most :data:`MAX_TERMS` features on
   the standardised dictionary; a feature is *stable* when chosen in at least
   :data:`MIN_FREQUENCY` of them.
4. **Fit and prune.**  Least squares of the stable features on every identification
   sample (rows weighted as the joint fits weigh the files), then backward elimination:
   a feature whose removal raises the effective BIC by less than ``-MAX_DELTA_BIC`` goes.
   A Gaussian profile's centre and width are then refined by bounded least squares, and
   the smooth sign's width of the chosen sign features (:data:`SIGN_RANGE_M_S`).
5. **Score** exactly as a candidate: the held-out gain ``1 − √(SSE_after/SSE_before)``
   and the effective ΔBIC on the identification files against the final model; the term
   is *significant* with a gain of at least ``MIN_SCORE`` and ``ΔBIC ≤ MAX_DELTA_BIC``.
   The diagnosis (``selection._discover``) then fits the term *with* the model
   (:func:`refit_with_term`: the paper's parameters, the effects, the chain's delay and
   the term's coefficients in one joint fit) and scores that fit the same way.
6. **Reading.**  The expression with units, the variables it depends on and the family
   hint of its largest part (:data:`HINTS`).

With ``free`` (:class:`ModelFree`) the model's own parameters are free to first order
beside the term in steps 3–5: their slopes are projected out of the target and of every
column, and each term is scored with the parameters' step that goes with it.

The term is additive on the damper's force and linear in its coefficients; the
coefficients' σ are the least-squares ones inflated for the residual's lag-1
autocorrelation, as the joint fits' are.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.base import TERM_PREFIX, Record, delay_rig
from damper_emulator.diagnose.candidates import Parameter
from damper_emulator.diagnose.joint import JOINT_NFEV, joint_fit
from damper_emulator.diagnose.statistics import delta_bic, lag1
from damper_emulator.diagnose.term_trust import per_file_coefficients, spread, stable_over
from damper_emulator.model.compressible import DamperModel
from damper_emulator.model.discovered import (
    N_TERMS,
    TERM_ABS_STROKE_SIGN,
    TERM_ACCELERATION,
    TERM_ENERGY,
    TERM_FIELDS,
    TERM_LAG,
    TERM_P_COM_SIGN,
    TERM_P_DROP,
    TERM_P_REB_SIGN,
    TERM_PROFILE,
    TERM_SIGN,
    TERM_STROKE,
    TERM_STROKE_CUBE,
    TERM_STROKE_SIGN,
    TERM_STROKE_SQ,
    TERM_STROKE_SQ_SIGN,
    TERM_STROKE_SQ_VEL,
    TERM_STROKE_VEL,
    TERM_TEMPERATURE,
    TERM_VELOCITY,
    TERM_VELOCITY_CUBE,
    TERM_VELOCITY_SQ,
    feature_history,
    lag_history,
    profile_history,
)
from damper_emulator.params import DiscoveredTermParams, ExtensionParams
from damper_emulator.validation import simulate_measured

__all__ = ["FEATURES", "Discovery", "Feature", "FeatureSource", "ModelFree", "Motion",
           "discover", "features"]

#: the smooth sign of velocity: ``tanh(ẋ / V_SIGN)`` [m/s] (a seal's pre-sliding range)
V_SIGN_M_S = 0.005
#: first-order lags of the model's force tried as features [s]
LAGS_S = (0.002, 0.005, 0.01)
#: Gaussian position profiles: ``(centre, width)`` as fractions of the largest |stroke|
#: of the identification files; a coarse row and a fine one (a zone a few mm long within
#: the chirp's stroke, a fifth of the quasi-static test's, needs the fine)
GAUSS_GRID = (*((c, 0.2) for c in (-0.6, -0.3, 0.0, 0.3, 0.6)),
              *((0.1 * k, 0.1) for k in range(-4, 5)))
#: stability selection: subsamples, the length of a block [s], the fraction of the
#: subsamples a stable feature is chosen in, the most features of a term
SUBSAMPLES = 40
BLOCK_S = 0.25
MIN_FREQUENCY = 0.7
MAX_TERMS = 3
#: the features of a damping polynomial in the stroke (x·ẋ, x²·ẋ), which the local
#: dictionary leaves to the zones: fitted on a chirp's short stroke, a polynomial grows
#: without bound on a longer one, a zone does not
POLYNOMIAL_DAMPING = (TERM_STROKE_VEL, TERM_STROKE_SQ_VEL)
#: the subsamples are drawn with this seed: a diagnosis is reproducible
SEED = 0

#: the family hint of each variable a feature depends on (the largest part's wins)
HINTS = {"acceleration": "inertia", "delay": "valve_dynamics",
         "temperature": "thermal", "energy": "thermal", "friction": "friction",
         "stroke·velocity": "position_dependent", "stroke": "end_stop",
         "stroke (linear)": "gas_spring", "stroke (even)": "gas_spring",
         "pressure": "valve_dynamics",
         # a term of velocity alone: a valve characteristic the paper's law cannot follow
         "velocity": "valve_dynamics"}


@dataclass
class Motion:
    """What the features of one record are made of: the measured motion, the final
    model's force and chamber pressures on it, the features the compiled step evaluates
    (:func:`damper_emulator.model.discovered.feature_history`, ``(n, N_TERMS)``), and the
    record's reference scales."""

    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    temperature: np.ndarray | None
    force_model: np.ndarray
    terms: np.ndarray
    #: the largest |stroke| of the identification files [m] (the Gaussians' scale)
    x_ref: float
    #: the mean temperature of the identification files [°C]
    t_ref: float
    #: the model's chamber pressures [Pa] (the features' inputs at another sign width)
    p_reb: np.ndarray | None = None
    p_com: np.ndarray | None = None
    _at_sign: dict[float, np.ndarray] = field(default_factory=dict, repr=False)

    def terms_at(self, v_sign: float) -> np.ndarray:
        """The compiled features with the smooth sign ``tanh(ẋ / v_sign)`` [m/s]."""
        if v_sign == V_SIGN_M_S or self.p_reb is None or self.p_com is None:
            return self.terms
        if v_sign not in self._at_sign:
            out = np.empty_like(self.terms)
            temp = (np.full(self.t.size, math.nan) if self.temperature is None
                    else np.asarray(self.temperature, dtype=float))
            feature_history(self.t, self.x, self.v, temp, self.force_model, self.p_reb,
                            self.p_com, v_sign, self.t_ref, 0.0, 0.0, LAGS_S[0], out)
            self._at_sign[v_sign] = out
        return self._at_sign[v_sign]

    @property
    def a(self) -> np.ndarray:
        """The acceleration [m/s²] as the step evaluates it."""
        out: np.ndarray = self.terms[:, TERM_ACCELERATION]
        return out

    @property
    def energy(self) -> np.ndarray:
        """The energy the model dissipated since the record's start [J]."""
        out: np.ndarray = self.terms[:, TERM_ENERGY] / np.where(
            self.force_model == 0.0, np.nan, self.force_model)
        return out


@dataclass(frozen=True)
class Feature:
    """One column of the dictionary: its symbol, the unit of its coefficient, the
    variable it names (a key of :data:`HINTS`), its index in the compiled features
    (:mod:`damper_emulator.model.discovered`), and for a zone its centre and width [m],
    for a lag its time constant [s]."""

    symbol: str
    unit: str
    variable: str
    index: int
    #: the parameters of a profile refined after selection (centre, width) [m]
    profile: tuple[float, float] | None = None
    lag_s: float | None = None
    #: for a feature of the smooth sign ``tanh(ẋ / v_s)``, its ``v_s`` [m/s]
    sign_m_s: float | None = None
    #: a known physical form whose coefficient is positive (a mass of ẍ, a damping of ẋ,
    #: a friction of the sign, a stiffness of x): fitted within that bound, and not
    #: taken where the data want it negative (it would not be that physics)
    positive: bool = False

    def text(self, c: float) -> str:
        return f"{c:+.4g} {self.unit} · {self.symbol}"

    def fn(self, m: Motion) -> np.ndarray:
        """The feature's values over the record ``m``."""
        out = np.empty_like(m.t)
        if self.profile is not None:
            profile_history(m.x, m.v, self.profile[0], self.profile[1], out)
        elif self.lag_s is not None:
            lag_history(m.t, m.force_model, self.lag_s, out)
        elif self.sign_m_s is not None:
            out[:] = m.terms_at(self.sign_m_s)[:, self.index]
        else:
            out[:] = m.terms[:, self.index]
        return out


def profile_feature(centre: float, width: float) -> Feature:
    """The Gaussian profile feature at ``centre`` and ``width`` [m]."""
    return Feature(f"exp(−(x − {1e3 * centre:.3g} mm)² / (2 · ({1e3 * width:.3g} mm)²)) · ẋ",
                   "N·s/m", "stroke·velocity", TERM_PROFILE, (centre, width), positive=True)


#: the features of the smooth sign: index, the factor's symbol, the coefficient's unit,
#: whether it is a known form with a positive coefficient (a friction)
SIGN_FEATURES = ((TERM_SIGN, "", "N", True), (TERM_STROKE_SIGN, "x · ", "N/m", False),
                 (TERM_STROKE_SQ_SIGN, "x² · ", "N/m²", False),
                 (TERM_ABS_STROKE_SIGN, "|x| · ", "N/m", False),
                 (TERM_P_COM_SIGN, "p_c · ", "m²", False),
                 (TERM_P_REB_SIGN, "p_r · ", "m²", False))
#: the range of a refined sign width [m/s]: a seal's pre-sliding, a fraction of a mm/s,
#: up to the dictionary's own width (a wider "sign" is a damping of ẋ, which the dictionary
#: holds as such, and a polynomial times it grows without bound beyond the files' speeds)
SIGN_RANGE_M_S = (2e-4, V_SIGN_M_S)


def sign_feature(index: int, v_sign: float) -> Feature:
    """The feature of the smooth sign of index ``index`` (:data:`SIGN_FEATURES`) at the
    width ``v_sign`` [m/s]."""
    factor, unit, positive = next((f, u, p) for i, f, u, p in SIGN_FEATURES if i == index)
    return Feature(f"{factor}tanh(ẋ / {1e3 * v_sign:.3g} mm/s)", unit, "friction", index,
                   positive=positive, sign_m_s=v_sign)


def _features(x_ref: float) -> list[Feature]:
    sign = {i: sign_feature(i, V_SIGN_M_S) for i, *_ in SIGN_FEATURES}
    out = [
        Feature("ẍ", "kg", "acceleration", TERM_ACCELERATION, positive=True),
        Feature("ẋ", "N·s/m", "velocity", TERM_VELOCITY, positive=True),
        Feature("ẋ|ẋ|", "N·s²/m²", "velocity", TERM_VELOCITY_SQ, positive=True),
        Feature("ẋ³", "N·s³/m³", "velocity", TERM_VELOCITY_CUBE, positive=True),
        sign[TERM_SIGN],
        Feature("x", "N/m", "stroke (linear)", TERM_STROKE, positive=True),
        Feature("x²", "N/m²", "stroke (even)", TERM_STROKE_SQ),
        Feature("x³", "N/m³", "stroke", TERM_STROKE_CUBE),
        Feature("x · ẋ", "N·s/m²", "stroke·velocity", TERM_STROKE_VEL),
        Feature("x² · ẋ", "N·s/m³", "stroke·velocity", TERM_STROKE_SQ_VEL),
        sign[TERM_STROKE_SIGN], sign[TERM_STROKE_SQ_SIGN], sign[TERM_ABS_STROKE_SIGN],
        sign[TERM_P_COM_SIGN], sign[TERM_P_REB_SIGN],
        Feature("(p_r − p_c)", "m²", "pressure", TERM_P_DROP),
        Feature("E · F_model", "1/J", "energy", TERM_ENERGY),
    ]
    out += [profile_feature(c * x_ref, w * x_ref) for c, w in GAUSS_GRID]
    out += [Feature(f"(lag_{1e3 * tau:g}ms(F_model) − F_model)", "-", "delay", TERM_LAG,
                    lag_s=tau) for tau in LAGS_S]
    return out


def _temperature_features() -> list[Feature]:
    return [Feature("(T − T_ref) · F_model", "1/K", "temperature", TERM_TEMPERATURE)]


#: the dictionary's features for a stroke scale of 50 mm (the list :func:`features` uses
#: is built for the files' own scale; this one is for the documentation)
FEATURES = _features(0.05) + _temperature_features()


def motion(model: DamperModel, rec: Record, x_ref: float, t_ref: float) -> Motion:
    """The :class:`Motion` of ``rec`` under ``model`` (simulated once, before any
    chain; ``model`` without a discovered term)."""
    d = rec.data
    res = simulate_measured(model, d if d.acquisition is None else
                            _without_chain(d), rec.velocity)
    v = rec.velocity
    temp = d.temperature if d.temperature is not None else np.full(d.time.size, math.nan)
    terms = np.empty((d.time.size, N_TERMS))
    feature_history(d.time, d.displacement, v, np.asarray(temp, dtype=float), res.force_n,
                    res.rebound_pressure_pa, res.compression_pressure_pa, V_SIGN_M_S, t_ref,
                    0.0, 0.0, LAGS_S[0], terms)
    return Motion(d.time, d.displacement, v, d.temperature, res.force_n, terms, x_ref,
                  t_ref, res.rebound_pressure_pa, res.compression_pressure_pa)


def _without_chain(d: Any) -> Any:
    return dataclasses.replace(d, acquisition=None)


def scales(fit: Sequence[Record]) -> tuple[float, float, bool]:
    """``(x_ref, t_ref, has_temperature)`` of the identification records ``fit``: the
    largest |stroke| [m] (the Gaussian zones' scale) and the mean temperature [°C] (0
    without a temperature column)."""
    x_ref = max(float(np.max(np.abs(r.data.displacement))) for r in fit)
    temps = [r.data.temperature for r in fit if r.data.temperature is not None]
    t_ref = float(np.mean(np.concatenate(temps))) if temps else 0.0
    return x_ref, t_ref, bool(temps)


def features(model: DamperModel, records: Sequence[Record], rig: RigParams | None,
             fit_records: Sequence[Record]
             ) -> tuple[list[Feature], list[np.ndarray], list[Motion]]:
    """The dictionary (its features, and per record the matrix of their columns through
    the chain, counted samples only, and the record's :class:`Motion`) for ``model`` on
    ``records``; the scales from ``fit_records``."""
    x_ref, t_ref, has_temperature = scales(fit_records)
    feats = _features(x_ref) + (_temperature_features() if has_temperature else [])
    mats, motions = [], []
    for rec in records:
        m = motion(model, rec, x_ref, t_ref)
        cols = [rec.through_chain(f.fn(m), rig)[rec.start:] for f in feats]
        mats.append(np.column_stack(cols))
        motions.append(m)
    return feats, mats, motions


def term_params(feats: Sequence[Feature], coefficients: Sequence[float], t_ref: float
                ) -> DiscoveredTermParams:
    """The ``damper.extensions.discovered_term`` group of the term ``Σ cₖ fₖ`` (at most one
    zone, one lag and one sign width among ``feats``)."""
    values: dict[str, float] = {}
    for f, c in zip(feats, coefficients):
        values[TERM_FIELDS[f.index]] = values.get(TERM_FIELDS[f.index], 0.0) + float(c)
        if f.profile is not None:
            values["profile_center_m"], values["profile_width_m"] = f.profile
        if f.lag_s is not None:
            values["lag_time_constant_s"] = f.lag_s
    v_sign = next((f.sign_m_s for f in feats if f.sign_m_s is not None), V_SIGN_M_S)
    return DiscoveredTermParams(smooth_sign_velocity_m_s=v_sign,
                                reference_temperature_c=t_ref, **values)


@dataclass
class Discovery:
    """Result of :func:`discover`; :meth:`to_json` is the diagnosis JSON's
    ``discovered``."""

    ran: bool
    reason: str
    features: list[Feature] = field(default_factory=list)
    coefficients: np.ndarray = field(default_factory=lambda: np.zeros(0))
    std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    frequency: dict[str, float] = field(default_factory=dict)
    held_out_gain: float = 0.0
    delta_bic: float = 0.0
    significant: bool = False
    rms_held_out_before: dict[str, float] = field(default_factory=dict)
    rms_held_out_after: dict[str, float] = field(default_factory=dict)
    #: r.m.s. [N] of every record (fitted and held out) with the term added
    rms_after: dict[str, float] = field(default_factory=dict)
    #: per held-out record: (the term's value, the force it is to explain, the main
    #: variable's values) for the plots
    series: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(
        default_factory=dict)
    #: the variable the largest part depends on, and its family hint
    main_variable: str = ""
    seconds: float = 0.0
    #: whether the coefficients come from the joint refit with the model
    #: (:func:`refit_with_term`), and that fit's paper's parameters (and the delay, the
    #: coefficients) with their σ
    refitted: bool = False
    base_values: dict[str, float] = field(default_factory=dict)
    base_std: dict[str, float] = field(default_factory=dict)
    #: the reference temperature of the term's temperature feature [°C]
    t_ref: float = 0.0
    #: after the joint refit: the values and σ of the effects fitted with the term, in
    #: their order (``accepted`` of :func:`refit_with_term`)
    effect_values: list[dict[str, float]] = field(default_factory=list)
    effect_std: list[dict[str, float]] = field(default_factory=list)
    #: after the joint refit: the model with the term as its ``discovered_term``
    #: extension (what ``params_with_effect.yaml`` holds)
    model: DamperModel | None = None
    #: after the joint refit: each part's coefficient fitted on each file alone (the
    #: model held), with its 1σ, by file name
    per_file: dict[str, list[tuple[float, float]]] = field(default_factory=dict)

    def stability(self) -> tuple[bool, str]:
        """Whether every part's coefficient is one over the files (:func:`stable_over`),
        and why not."""
        if not self.per_file:
            return False, "not fitted per file"
        for k, f in enumerate(self.features):
            ok, why = stable_over({n: v[k] for n, v in self.per_file.items()},
                                  float(self.coefficients[k]))
            if not ok:
                return False, f"{f.symbol}: {why}"
        return True, "every part's coefficient is one over the files"

    def trust(self) -> str:
        """Whether the term is ready to trust, in words: significant on the held-out
        files and the same in every file."""
        if not self.features:
            return "no term"
        stable, why = self.stability()
        if not self.significant:
            return (f"not ready: its held-out gain {100 * self.held_out_gain:+.1f} % is not "
                    "significant")
        if not stable:
            return f"not ready: it is not the same in every file ({why})"
        return (f"ready: held-out gain {100 * self.held_out_gain:+.1f} %, and {why}")

    def extension(self) -> DiscoveredTermParams:
        """The term as the ``damper.extensions.discovered_term`` group."""
        return term_params(self.features, self.coefficients, self.t_ref)

    @property
    def expression(self) -> str:
        return " ".join(f.text(c) for f, c in zip(self.features, self.coefficients))

    @property
    def variables(self) -> list[str]:
        return sorted({f.variable for f in self.features})

    @property
    def family_hint(self) -> str | None:
        return HINTS.get(self.main_variable) if self.features else None

    def to_json(self) -> dict[str, Any]:
        return {
            "ran": self.ran, "reason": self.reason,
            "expression": self.expression if self.features else None,
            "variables": self.variables,
            "coefficients": [{"term": f.symbol, "value": float(c),
                              "std": float(s) if math.isfinite(s) else None,
                              "unit": f.unit}
                             for f, c, s in zip(self.features, self.coefficients, self.std)],
            "selection_frequency": self.frequency,
            "held_out_gain": self.held_out_gain, "delta_bic": self.delta_bic,
            "significant": self.significant, "family_hint": self.family_hint,
            "rms_held_out_before": self.rms_held_out_before,
            "rms_held_out_after": self.rms_held_out_after,
            "refitted_with_model": self.refitted,
            "per_file": {n: [{"value": float(c), "std": float(sd) if math.isfinite(sd)
                              else None} for c, sd in v] for n, v in self.per_file.items()},
            "stable": self.stability()[0] if self.features else None,
            "trust": self.trust(),
            "seconds": round(self.seconds, 2)}


#: the narrowest zone a profile is refined or fitted to, as a fraction of the files'
#: largest stroke (its centre within that stroke, its width up to all of it)
MIN_PROFILE_WIDTH = 0.02


def profile_bounds(x_ref: float) -> tuple[np.ndarray, np.ndarray]:
    """The bounds ``(lo, hi)`` of a zone's ``(centre, width)`` [m] on files whose largest
    |stroke| is ``x_ref`` (:data:`MIN_PROFILE_WIDTH`)."""
    return np.array([-x_ref, MIN_PROFILE_WIDTH * x_ref]), np.array([x_ref, x_ref])


def refine_profile(f: Feature, others: np.ndarray, y: np.ndarray, w_rows: np.ndarray,
                   fit: Sequence[Record], motions: Sequence[Motion],
                   rig: RigParams | None) -> Feature:
    """The Gaussian profile ``f`` with its centre and width fitted by bounded least
    squares to ``y``, the missing force over the counted samples of ``fit`` weighted by
    ``w_rows``, together with the weighted columns ``others`` (their coefficients solved
    at each step; the profile within the files' stroke, its width from 2 % to the whole
    stroke)."""
    from scipy.optimize import least_squares

    assert f.profile is not None
    x_ref = motions[0].x_ref

    def resid(p: np.ndarray) -> np.ndarray:
        g = profile_feature(float(p[0]), float(p[1]))
        col = np.concatenate([r.through_chain(g.fn(m), rig)[r.start:]
                              for r, m in zip(fit, motions)]) * w_rows
        a = np.column_stack([col, others])
        beta, *_ = np.linalg.lstsq(a, y, rcond=None)
        out: np.ndarray = y - a @ beta
        return out

    lo, hi = profile_bounds(x_ref)
    sol = least_squares(resid, np.clip(np.array(f.profile), lo, hi), bounds=(lo, hi),
                        x_scale=np.array([0.1 * x_ref, 0.1 * x_ref]), max_nfev=40)
    return profile_feature(float(sol.x[0]), float(sol.x[1]))


#: the quantity each variable is plotted against: (label with unit, scale to it, field of
#: :class:`Motion`)
PLOTTED = {"acceleration": ("ẍ [m/s²]", 1.0, "a"), "velocity": ("ẋ [m/s]", 1.0, "v"),
           "friction": ("ẋ [m/s]", 1.0, "v"), "delay": ("ẋ [m/s]", 1.0, "v"),
           "pressure": ("ẋ [m/s]", 1.0, "v"), "stroke": ("x [mm]", 1e3, "x"),
           "stroke (linear)": ("x [mm]", 1e3, "x"), "stroke (even)": ("x [mm]", 1e3, "x"),
           "stroke·velocity": ("x [mm]", 1e3, "x"),
           "temperature": ("T [°C]", 1.0, "temperature"),
           "energy": ("dissipated energy [kJ]", 1e-3, "energy")}


def variable_values(variable: str, m: Motion) -> np.ndarray:
    """The values of ``variable`` (a key of :data:`PLOTTED`) over a record, in the plot's
    unit."""
    _, scale, name = PLOTTED[variable]
    values = getattr(m, name)
    out: np.ndarray = (np.zeros_like(m.t) if values is None else values * scale)
    return out


def _blocks(records: Sequence[Record]) -> list[np.ndarray]:
    """Index arrays of :data:`BLOCK_S` blocks into the concatenated counted samples."""
    out, offset = [], 0
    for rec in records:
        t = rec.data.time[rec.start:]
        n = t.size
        edges = np.searchsorted(t, np.arange(t[0], t[-1] + BLOCK_S, BLOCK_S))
        edges = np.unique(np.append(edges, n))
        out += [np.arange(offset + a, offset + b) for a, b in itertools.pairwise(edges)
                if b > a]
        offset += n
    return out


def stability(x: np.ndarray, y: np.ndarray, blocks: Sequence[np.ndarray],
              rng: np.random.Generator) -> np.ndarray:
    """Selection frequency of each column of ``x`` (standardised) over
    :data:`SUBSAMPLES` halves of ``blocks``, each regressed by orthogonal matching pursuit
    with at most :data:`MAX_TERMS` columns."""
    from sklearn.linear_model import OrthogonalMatchingPursuit

    scale = np.sqrt(np.mean(x * x, axis=0))
    scale[scale == 0.0] = 1.0
    xs = x / scale
    count = np.zeros(x.shape[1])
    k = min(MAX_TERMS, x.shape[1])
    for _ in range(SUBSAMPLES):
        pick = rng.choice(len(blocks), size=max(len(blocks) // 2, 1), replace=False)
        idx = np.concatenate([blocks[i] for i in pick])
        omp = OrthogonalMatchingPursuit(n_nonzero_coefs=k, fit_intercept=False)
        omp.fit(xs[idx], y[idx])
        count += omp.coef_ != 0.0
    freq: np.ndarray = count / SUBSAMPLES
    return freq


def _one_of_each(order: Sequence[int], feats: Sequence[Feature]) -> list[int]:
    """``order`` without the features whose coefficient an earlier one already holds
    (the model's term has one of each, and one zone, one lag)."""
    out: list[int] = []
    for j in order:
        if all(feats[k].index != feats[j].index for k in out):
            out.append(j)
    return out


def _bic(fit_res: Sequence[np.ndarray], ref_res: Sequence[np.ndarray], k: int) -> float:
    """Effective ΔBIC of residuals ``fit_res`` against ``ref_res`` (the same records)
    with ``k`` added parameters, as a candidate's (``StepFit.score_against``)."""
    return delta_bic(((r.size, lag1(r), float(np.mean(r * r)), float(np.mean(r0 * r0)))
                      for r, r0 in zip(fit_res, ref_res)), k)


def _split_rows(rows: np.ndarray, like: Sequence[np.ndarray]) -> list[np.ndarray]:
    """``rows`` (the records' samples concatenated) split as ``like`` is."""
    return np.split(rows, np.cumsum([r.size for r in like])[:-1])


@dataclass(frozen=True)
class ModelFree:
    """The model's own parameters free to first order beside a term: its force's slopes
    with respect to every parameter a joint fit frees (:func:`~damper_emulator.diagnose.
    joint.model_jacobians`), over the identification rows weighted as the regression
    weighs them (``fit``) and over the held-out records (``held``), counted samples
    concatenated.

    A regression with them (:func:`discover`'s ``free``) solves every term together
    with a linear step of the model's parameters (``δ``), and scores it so: the term must
    explain what a refit of the model could not.  A model whose fit bent its parameters
    towards a missing effect (a cavity's gas volume four times softer, to follow part of a
    damping zone) leaves a residual that shows the bend, not the effect; with the
    parameters free, the effect's own form is what is left."""

    fit: np.ndarray
    held: np.ndarray

    def step(self, target: np.ndarray) -> np.ndarray:
        """The least-squares ``δ`` of the weighted identification rows ``target``
        (a vector or columns)."""
        out: np.ndarray = np.linalg.lstsq(self.fit, target, rcond=None)[0]
        return out

    def left(self, target: np.ndarray) -> np.ndarray:
        """``target`` (weighted identification rows) less what a step of the parameters
        explains."""
        out: np.ndarray = target - self.fit @ self.step(target)
        return out


@dataclass
class _Regression:
    """One dictionary's regression (steps 3–6): the features, their columns per record
    (identification and held out), the residuals the term is to explain, and the
    weighted design matrix ``x`` and target ``y`` over the identification samples."""

    feats: list[Feature]
    fit_mats: list[np.ndarray]
    held_mats: list[np.ndarray]
    fit_res: list[np.ndarray]
    held_res: list[np.ndarray]
    w_rows: np.ndarray
    x: np.ndarray
    y: np.ndarray
    max_delta_bic: float
    #: the model's parameters free to first order beside the term (``fit_res``,
    #: ``held_res`` are then the residuals after the model's own step, ``δ₀``)
    free: ModelFree | None = None

    @classmethod
    def of(cls, feats: list[Feature], fit_mats: list[np.ndarray],
           held_mats: list[np.ndarray], fit_res: list[np.ndarray],
           held_res: list[np.ndarray], weights: Sequence[float],
           max_delta_bic: float, free: ModelFree | None = None) -> _Regression:
        """The rows weighted as the joint fits weigh the files; ``y`` the missing force
        ``F_meas − F_model`` (with ``free``: after the model's own step ``δ₀``, which the
        term's must then beat)."""
        w_rows = np.concatenate([np.full(r.size, w) for r, w in zip(fit_res, weights)])
        if free is not None:
            delta0 = free.step(-np.concatenate(fit_res) * w_rows)
            fit_res = _split_rows(np.concatenate(fit_res)
                                  + (free.fit @ delta0) / w_rows, fit_res)
            held_res = _split_rows(np.concatenate(held_res) + free.held @ delta0, held_res)
        return cls(feats, fit_mats, held_mats, fit_res, held_res, w_rows,
                   np.vstack(fit_mats) * w_rows[:, None], -np.concatenate(fit_res) * w_rows,
                   max_delta_bic, free)

    def design(self, cols: Sequence[int]) -> np.ndarray:
        """The weighted columns ``cols``, less what the model's free parameters explain
        of them (with :attr:`free`; the target :attr:`y` already is)."""
        a = self.x[:, cols]
        return a if self.free is None else self.free.left(a)

    def beside(self, cols: Sequence[int]) -> np.ndarray:
        """The weighted columns ``cols`` and the model's free parameters' (with
        :attr:`free`): what a refinement solves together with the column it refines."""
        a = self.x[:, cols]
        return a if self.free is None else np.column_stack([a, self.free.fit])

    def solve(self, cols: Sequence[int]) -> np.ndarray:
        """Least squares of the columns ``cols`` on the weighted identification rows
        (with the model's free parameters beside them: their coefficients only)."""
        beta, *_ = np.linalg.lstsq(self.design(cols), self.y, rcond=None)
        out: np.ndarray = beta
        return out

    def after(self, cols: Sequence[int], beta: np.ndarray, held: bool = False
              ) -> list[np.ndarray]:
        """The residuals with the term ``Σ βₖ fₖ`` (of ``cols``) added (and the model's
        parameters' step that goes with it, with :attr:`free`)."""
        mats, res = (self.held_mats, self.held_res) if held else (self.fit_mats,
                                                                   self.fit_res)
        out = [r + m[:, cols] @ beta for r, m in zip(res, mats)]
        if self.free is None or not cols:
            return out
        # the parameters' step with the term: δ − δ₀ = −P x β (P the parameters' least
        # squares on the weighted rows; the target after δ₀ is orthogonal to them)
        delta = -self.free.step(self.x[:, cols] @ beta)
        step = self.free.held @ delta if held else (self.free.fit @ delta) / self.w_rows
        return _split_rows(np.concatenate(out) + step, out)

    def bic(self, cols: Sequence[int]) -> float:
        """The effective ΔBIC of the least-squares term of ``cols`` (none: 0 terms)."""
        beta = self.solve(cols) if cols else np.zeros(0)
        return _bic(self.after(cols, beta), self.fit_res, len(cols))

    def prune(self, cols: list[int]) -> list[int]:
        """Backward elimination by the effective BIC: the feature whose removal costs
        least goes while that cost is under ``-max_delta_bic``."""
        while cols:
            full = self.bic(cols)
            worst, worst_gain = None, 0.0
            for j in cols:
                cost = self.bic([c for c in cols if c != j]) - full
                if cost < -self.max_delta_bic and (worst is None or cost < worst_gain):
                    worst, worst_gain = j, cost
            if worst is None:
                break
            cols = [c for c in cols if c != worst]
        return cols

    def replace(self, j: int, feature: Feature, fit: Sequence[Record],
                fit_motion: Sequence[Motion], held: Sequence[Record],
                held_motion: Sequence[Motion], rig: RigParams | None) -> None:
        """Feature ``j`` becomes ``feature`` (a refined profile), in every column."""
        self.feats[j] = feature
        col = [r.through_chain(feature.fn(m), rig)[r.start:] for r, m in zip(fit, fit_motion)]
        self.x[:, j] = np.concatenate(col) * self.w_rows
        for mat, c in zip(self.fit_mats, col):
            mat[:, j] = c
        for rec, m, mat in zip(held, held_motion, self.held_mats):
            mat[:, j] = rec.through_chain(feature.fn(m), rig)[rec.start:]

    def std(self, cols: Sequence[int], beta: np.ndarray) -> np.ndarray:
        """σ of the coefficients: ``(XᵀX)⁻¹ s²``, inflated for an AR(1) residual."""
        a = self.design(cols)
        resid = self.y - a @ beta
        rho = max(lag1(r) for r in self.after(cols, beta))
        s2 = float(np.dot(resid, resid)) / max(resid.size - len(cols), 1) \
            * (1 + rho) / (1 - rho)
        try:
            cov = np.linalg.inv(a.T @ a) * s2
        except np.linalg.LinAlgError:
            return np.full(len(cols), math.inf)
        out: np.ndarray = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        return out


def _stable(reg: _Regression, fit: Sequence[Record], say: Callable[[str], None]
            ) -> tuple[list[int], dict[str, float]]:
    """Step 3: the stable features (at most :data:`MAX_TERMS`, one of each kind), and the
    six most frequent features' selection frequencies."""
    keep = [int(j) for j in np.flatnonzero(np.any(reg.x != 0.0, axis=0))]
    freq = np.zeros(len(reg.feats))
    design = reg.design(keep)
    freq[keep] = stability(design, reg.y, _blocks(fit), np.random.default_rng(SEED))
    order = [int(j) for j in np.argsort(-freq)]
    if reg.free is not None:
        # of equal frequency, the feature that explains more of the missing force alone
        # first: with the model's parameters free, several zones are chosen in every
        # subsample, and the one kept must be where the force is (the plain discovery
        # keeps its order, which the benchmark's answers were measured with)
        alone = np.zeros(len(reg.feats))
        norms = np.einsum("ij,ij->j", design, design)
        alone[keep] = (design.T @ reg.y) ** 2 / np.where(norms > 0.0, norms, 1.0)
        order = sorted(order, key=lambda j: (-freq[j], -alone[j]))
    chosen = _one_of_each([j for j in order if freq[j] >= MIN_FREQUENCY],
                          reg.feats)[:MAX_TERMS]
    frequency = {reg.feats[j].symbol: float(freq[j]) for j in np.argsort(-freq)[:6]}
    say("discovery: selection frequencies " + ", ".join(
        f"{k} {v:.2f}" for k, v in frequency.items()))
    return chosen, frequency


def _refine_profiles(reg: _Regression, chosen: list[int], fit: Sequence[Record],
                     fit_motion: Sequence[Motion], held: Sequence[Record],
                     held_motion: Sequence[Motion], rig: RigParams | None) -> None:
    """Step 4's refinement: each chosen Gaussian profile's centre and width."""
    for j in chosen:
        f = reg.feats[j]
        if f.profile is not None:
            refined = refine_profile(f, reg.beside([k for k in chosen if k != j]), reg.y,
                                     reg.w_rows, fit, fit_motion, rig)
            reg.replace(j, refined, fit, fit_motion, held, held_motion, rig)


def _refine_sign(reg: _Regression, chosen: list[int], fit: Sequence[Record],
                 fit_motion: Sequence[Motion], held: Sequence[Record],
                 held_motion: Sequence[Motion], rig: RigParams | None,
                 say: Callable[[str], None]) -> None:
    """Step 4's refinement of the smooth sign's width (one for the term, as the compiled
    term has): a seal's pre-sliding is its own, not the dictionary's 5 mm/s.  A bounded
    search on ``log v_s`` over :data:`SIGN_RANGE_M_S` for the least weighted squares of
    the chosen features (their coefficients solved at each width)."""
    from scipy.optimize import minimize_scalar

    signs = [j for j in chosen if reg.feats[j].sign_m_s is not None]
    if not signs:
        return
    others = reg.beside([j for j in chosen if j not in signs])

    def columns(v_sign: float) -> np.ndarray:
        return np.column_stack([np.concatenate([
            r.through_chain(sign_feature(reg.feats[j].index, v_sign).fn(m), rig)[r.start:]
            for r, m in zip(fit, fit_motion)]) * reg.w_rows for j in signs])

    def sse(log_v: float) -> float:
        a = np.column_stack([columns(math.exp(log_v)), others])
        beta, *_ = np.linalg.lstsq(a, reg.y, rcond=None)
        r = reg.y - a @ beta
        return float(np.dot(r, r))

    lo, hi = (math.log(v) for v in SIGN_RANGE_M_S)
    sol = minimize_scalar(sse, bounds=(lo, hi), method="bounded",
                          options={"xatol": 0.05, "maxiter": 25})
    v_sign = math.exp(float(sol.x))
    if not sol.fun < sse(math.log(V_SIGN_M_S)):
        return
    say(f"discovery: the smooth sign's width refined to {1e3 * v_sign:.3g} mm/s")
    for j in signs:
        reg.replace(j, sign_feature(reg.feats[j].index, v_sign), fit, fit_motion, held,
                    held_motion, rig)


def _physical(reg: _Regression, chosen: list[int], say: Callable[[str], None]
              ) -> list[int]:
    """A known form of the wrong sign (a negative mass) is not that physics: it goes, and
    what is left is pruned again."""
    while chosen:
        beta = reg.solve(chosen)
        wrong = [j for j, b in zip(chosen, beta) if reg.feats[j].positive and b < 0.0]
        if not wrong:
            break
        say("discovery: " + ", ".join(reg.feats[j].symbol for j in wrong)
            + " of the wrong sign for its physics: left out")
        chosen = reg.prune([j for j in chosen if j not in wrong])
    return chosen


def _scored(reg: _Regression, chosen: list[int], frequency: dict[str, float],
            fit: Sequence[Record], held: Sequence[Record], held_motion: Sequence[Motion],
            before: dict[str, float], min_score: float, t0: float) -> Discovery:
    """Step 5 and 6: the term of ``chosen`` scored as a candidate, and read."""
    import time

    beta = reg.solve(chosen)
    fit_after = reg.after(chosen, beta)
    held_after = reg.after(chosen, beta, held=True)
    sse0 = sum(float(np.dot(r, r)) for r in reg.held_res)
    sse1 = sum(float(np.dot(r, r)) for r in held_after)
    gain = 1.0 - math.sqrt(sse1 / sse0) if sse0 > 0 else 0.0
    dbic = _bic(fit_after, reg.fit_res, len(chosen))
    stacked = np.vstack(reg.held_mats)
    parts = [float(np.sqrt(np.mean((stacked[:, j] * b) ** 2))) for j, b in zip(chosen, beta)]
    main = chosen[int(np.argmax(parts))]
    feats = reg.feats
    return Discovery(
        True, "", [feats[j] for j in chosen], beta, reg.std(chosen, beta), frequency, gain,
        dbic, bool(gain >= min_score and dbic <= reg.max_delta_bic), before,
        {r.name: float(np.sqrt(np.mean(a * a))) for r, a in zip(held, held_after)},
        {r.name: float(np.sqrt(np.mean(a * a)))
         for r, a in zip([*fit, *held], [*fit_after, *held_after])},
        {r.name: (m[:, chosen] @ beta, -x0, variable_values(feats[main].variable, mo)[r.start:])
         for r, m, x0, mo in zip(held, reg.held_mats, reg.held_res, held_motion)},
        feats[main].variable, time.perf_counter() - t0, t_ref=scales(fit)[1])


def discover(model: DamperModel, rig: RigParams | None, fit: Sequence[Record],
             held: Sequence[Record], weights: Sequence[float], floor: float,
             structure: float, structure_limit: float, min_score: float,
             max_delta_bic: float, progress: Callable[[str], None] | None = None,
             dictionaries: Sequence[bool] = (False,), free: ModelFree | None = None
             ) -> Discovery:
    """Discover a term in the residual of ``model`` (with the estimated chain ``rig``) on
    the identification records ``fit`` (weighted by ``weights``), scored on ``held``;
    the gate's ``floor`` and ``structure`` (held-out r.m.s. over its noise level) against
    ``structure_limit``, the significance rules ``min_score`` and ``max_delta_bic``
    (module docstring).  ``dictionaries``: the dictionaries regressed on, each ``local``
    or not (local: without :data:`POLYNOMIAL_DAMPING`, a damping that changes over the
    stroke as the zones only, bounded where the files did not go), from one computation
    of the features; the term of the largest held-out gain is returned (of equal gains the
    first).  ``free``: the model's parameters free to first order beside the term
    (:class:`ModelFree`, their slopes at ``model``)."""
    import time

    t0 = time.perf_counter()
    say = progress or (lambda msg: None)
    fit_res = [r.residual(model, rig=rig) for r in fit]
    held_res = [r.residual(model, rig=rig) for r in held]
    held_rms = math.sqrt(sum(float(np.dot(r, r)) for r in held_res)
                         / max(sum(r.size for r in held_res), 1))
    before = {r.name: float(np.sqrt(np.mean(x * x))) for r, x in zip(held, held_res)}
    if held_rms <= floor or structure <= structure_limit:
        return Discovery(False, f"nothing to discover: held-out r.m.s. {held_rms:.2f} N "
                         f"(floor {floor:.2f} N), structure ratio {structure:.2f} "
                         f"(limit {structure_limit})", rms_held_out_before=before,
                         seconds=time.perf_counter() - t0)
    all_feats, all_fit, fit_motion = features(model, fit, rig, fit)
    _, all_held, held_motion = features(model, held, rig, fit)

    def regress(reg: _Regression) -> Discovery:
        """Steps 3–6 on one dictionary."""
        chosen, frequency = _stable(reg, fit, say)
        chosen = reg.prune(chosen)
        if not chosen:
            return Discovery(True, "no feature is stable", frequency=frequency,
                             rms_held_out_before=before, seconds=time.perf_counter() - t0)
        _refine_profiles(reg, chosen, fit, fit_motion, held, held_motion, rig)
        _refine_sign(reg, chosen, fit, fit_motion, held, held_motion, rig, say)
        # what the refined profile now explains, the others no longer need to
        chosen = _physical(reg, reg.prune(chosen), say)
        if not chosen:
            return Discovery(True, "no feature is significant", frequency=frequency,
                             rms_held_out_before=before, seconds=time.perf_counter() - t0)
        found = _scored(reg, chosen, frequency, fit, held, held_motion, before, min_score,
                        t0)
        say(f"discovery: {found.expression}: held-out gain {100 * found.held_out_gain:+.1f} "
            f"%, ΔBIC {found.delta_bic:.0f}{' (significant)' if found.significant else ''}")
        return found

    best: Discovery | None = None
    for local in dictionaries:
        cols = [j for j, f in enumerate(all_feats)
                if not (local and f.index in POLYNOMIAL_DAMPING)]
        # (copies: the refined zone replaces its column)
        one = regress(_Regression.of([all_feats[j] for j in cols],
                                     [m[:, cols] for m in all_fit],
                                     [m[:, cols] for m in all_held], fit_res, held_res,
                                     weights, max_delta_bic, free))
        if best is None or (one.features and (
                not best.features or one.held_out_gain > best.held_out_gain)):
            if best is not None:
                say("discovery: the term of the dictionary "
                    + ("with the zones for the damping polynomials" if local else "in full")
                    + " is taken")
            best = one
    assert best is not None  # at least one dictionary
    return best


def _profile_names(k: int) -> tuple[str, str]:
    """The joint fit's names of part ``k``'s zone centre and width [m]."""
    return f"{TERM_PREFIX}centre_{k}", f"{TERM_PREFIX}width_{k}"


class FeatureSource:
    """The :class:`~damper_emulator.diagnose.base.TermSource` of the features ``feats``
    (their scales from the identification records ``fit``): what a joint fit adds.  A
    zone's centre and width are the fit's to move (:func:`_profile_names`)."""

    def __init__(self, feats: Sequence[Feature], fit: Sequence[Record]):
        self.feats = list(feats)
        self.x_ref, self.t_ref, _ = scales(fit)

    def __call__(self, model: DamperModel, rec: Record) -> tuple[np.ndarray, np.ndarray]:
        m = motion(model, rec, self.x_ref, self.t_ref)
        # (the file's own chain only: the estimated one is the fit's to apply)
        return (rec.through_chain(m.force_model, None),
                np.column_stack([f.fn(m) for f in self.feats]))

    def at(self, rec: Record, cols: np.ndarray, values: Mapping[str, float]) -> np.ndarray:
        out = cols
        for k, f in enumerate(self.feats):
            centre, width = _profile_names(k)
            if f.profile is None or centre not in values:
                continue
            if out is cols:
                out = cols.copy()
            column = np.empty(cols.shape[0])
            profile_history(rec.data.displacement, rec.velocity, float(values[centre]),
                            float(values[width]), column)
            out[:, k] = column
        return out

    def parameters(self, coefficients: Sequence[float]
                   ) -> tuple[list[Parameter], dict[str, float]]:
        """The joint fit's parameters of the parts at ``coefficients``, and their start
        values: each coefficient within ten times its start (a known form within its
        physical bound: a mass is positive), a zone's centre within the files' stroke and
        its width from 2 % of it to all of it (:func:`profile_bounds`)."""
        params, values = [], {}
        bounds = profile_bounds(self.x_ref)
        for k, (f, c) in enumerate(zip(self.feats, coefficients)):
            span = max(10.0 * abs(c), 1e-12)
            params.append(Parameter(f"{TERM_PREFIX}{k}", 0.0 if f.positive else -span, span,
                                    float(c), False, f.unit))
            values[f"{TERM_PREFIX}{k}"] = float(c)
            if f.profile is not None:
                for name, v, lo, hi in zip(_profile_names(k), f.profile, *bounds):
                    v = min(max(v, float(lo)), float(hi))
                    params.append(Parameter(name, float(lo), float(hi), v, False, "m"))
                    values[name] = v
        return params, values

    def fitted(self, values: Mapping[str, float]) -> list[Feature]:
        """The features with each zone at its fitted centre and width in ``values``."""
        out = []
        for k, f in enumerate(self.feats):
            centre, width = _profile_names(k)
            out.append(profile_feature(float(values[centre]), float(values[width]))
                       if f.profile is not None and centre in values else f)
        return out


#: a part of a term whose coefficient after the joint refit is within this many σ of 0
#: is dropped (and the refit repeated without it)
MIN_T_RATIO = 3.0
def refit_with_term(found: Discovery, cfg: Any, base_values: Mapping[str, float],
                    accepted: Sequence[tuple[Any, Mapping[str, float]]],
                    fit: Sequence[Record], held: Sequence[Record],
                    weights: Sequence[float], ref_fit: Sequence[np.ndarray],
                    ref_held: Sequence[np.ndarray], min_score: float, max_delta_bic: float,
                    n_quasi_static: int = 1, nfev: int = JOINT_NFEV,
                    progress: Callable[[str], None] | None = None) -> Discovery:
    """The discovered term fitted *with* the model: the paper's parameters, the effects
    ``accepted`` (freed from their values), the estimated chain's delay and the term's
    coefficients in one joint fit (:func:`~damper_emulator.diagnose.joint.joint_fit`)
    from ``base_values`` and the discovery's coefficients, and from the paper's model
    identified again without the term's force; parts within :data:`MIN_T_RATIO` σ of 0
    (or not one over the files) are dropped, and the fit repeated from where the last
    one ended.  Scored against the model before (residuals
    ``ref_fit``, ``ref_held``) as a candidate is."""
    say = progress or (lambda msg: None)
    feats = list(found.features)
    coef = list(found.coefficients)
    first = True
    while feats:
        source = FeatureSource(feats, fit)
        params, start = source.parameters(coef)
        jf = joint_fit(cfg, fit, weights, {**base_values, **start}, accepted, None, nfev,
                       n_quasi_static, terms=source, term_parameters=params,
                       identify_without_term=first)
        # a part dropped: the fit again from where this one ended (its start chosen)
        base_values = {k: v for k, v in jf.base_values.items() if not k.startswith(TERM_PREFIX)}
        accepted = [(c, v) for (c, _), v in zip(accepted, jf.values)]
        first = False
        # a zone where the joint fit moved it
        feats = source.fitted(jf.base_values)
        source = FeatureSource(feats, fit)
        coef = [jf.base_values[f"{TERM_PREFIX}{k}"] for k in range(len(feats))]
        std = [jf.base_std.get(f"{TERM_PREFIX}{k}", math.inf) for k in range(len(feats))]
        weak = [k for k, (c, s) in enumerate(zip(coef, std))
                if not abs(c) > MIN_T_RATIO * s]
        if len(feats) == 1:
            break
        if weak:
            drop = min(weak, key=lambda k: abs(coef[k]) / std[k] if std[k] > 0 else 0.0)
            say(f"discovery: {feats[drop].symbol} dropped after the joint refit "
                f"({coef[drop]:.4g} ± {std[drop]:.2g} {feats[drop].unit})")
            del feats[drop], coef[drop]
            continue
        # a part that is not one over the files is not a property of the damper (it
        # takes the model's error at each file's speeds): the least stable goes
        models = jf.models(cfg, [c for c, _ in accepted], len(fit) + len(held),
                           n_quasi_static)
        per_file = per_file_coefficients(models, source, fit, held,
                                         delay_rig(jf.base_values))
        unstable = [k for k in range(len(feats))
                    if not stable_over({n: v[k] for n, v in per_file.items()}, coef[k])[0]]
        if not unstable or len(unstable) == len(feats):
            break
        drop = max(unstable, key=lambda k: spread({n: v[k] for n, v in per_file.items()},
                                                   coef[k]))
        say(f"discovery: {feats[drop].symbol} dropped after the joint refit: "
            f"{stable_over({n: v[drop] for n, v in per_file.items()}, coef[drop])[1]}")
        del feats[drop], coef[drop]
    models = jf.models(cfg, [c for c, _ in accepted], len(fit) + len(held), n_quasi_static)
    model = jf.model(cfg, [c for c, _ in accepted])
    rig = delay_rig(jf.base_values)
    # (the model at speed on every file, as the reference ``ref_fit`` was taken)
    fit_res = [r.term_residual(model, source, coef, rig) for r in fit]
    # each held-out record simulated once: its residual, the term, the parts, the plot
    x_ref, t_ref, _ = scales(fit)
    held_res, terms, cols_all, motions = [], [], [], []
    for rec in held:
        m = motion(model, rec, x_ref, t_ref)
        cols = np.column_stack([f.fn(m) for f in feats])
        term = rec.through_chain(cols @ np.asarray(coef), rig)[rec.start:]
        # the chain is linear: the model's force and the term through it together
        held_res.append(rec.through_chain(m.force_model, rig)[rec.start:] + term
                        - rec.data.force[rec.start:])
        terms.append(term)
        cols_all.append(cols)
        motions.append(m)
    sse0 = sum(float(np.dot(r, r)) for r in ref_held)
    sse1 = sum(float(np.dot(r, r)) for r in held_res)
    gain = 1.0 - math.sqrt(sse1 / sse0) if sse0 > 0 else 0.0
    dbic = _bic(fit_res, ref_fit, len(feats))
    stacked = np.vstack(cols_all)
    parts = [float(np.sqrt(np.mean(stacked[:, k] ** 2))) * abs(coef[k])
             for k in range(len(feats))]
    main = feats[int(np.argmax(parts))]
    series = {rec.name: (term, term - r, variable_values(main.variable, m)[rec.start:])
              for rec, term, r, m in zip(held, terms, held_res, motions)}
    out = Discovery(
        True, "", feats, np.array(coef), np.array(std), found.frequency, gain, dbic,
        bool(gain >= min_score and dbic <= max_delta_bic),
        {r.name: float(np.sqrt(np.mean(x * x))) for r, x in zip(held, ref_held)},
        {r.name: float(np.sqrt(np.mean(x * x))) for r, x in zip(held, held_res)},
        {r.name: float(np.sqrt(np.mean(x * x)))
         for r, x in zip([*fit, *held], [*fit_res, *held_res])},
        series, main.variable, found.seconds, refitted=True,
        base_values={k: float(v) for k, v in jf.base_values.items()},
        base_std={k: float(v) for k, v in jf.base_std.items()}, t_ref=t_ref,
        effect_values=[dict(v) for v in jf.values], effect_std=[dict(v) for v in jf.std])
    ext = model.cfg.damper.extensions or ExtensionParams()
    out.model = model.with_extensions(dataclasses.replace(ext,
                                                          discovered_term=out.extension()))
    out.per_file = per_file_coefficients(models, source, fit, held, rig)
    say(f"discovery, refitted with the model: {out.expression}: held-out gain "
        f"{100 * gain:+.1f} %, ΔBIC {dbic:.0f}{' (significant)' if out.significant else ''}"
        f"; {out.trust()}")
    return out
