"""The outcome of a diagnosis and how it is judged: the selection's thresholds, the
residual figures they are applied to (noise level, structure ratio, explained fraction,
floor), one step's fits (:class:`StepFit`) and the whole answer (:class:`Diagnosis`,
its JSON report and parameter file).  The selection itself is
:func:`damper_emulator.diagnose.selection.diagnose`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from damper_emulator.acquisition.chain import chain_json, estimated_rig
from damper_emulator.acquisition.rig import RigParams, rig_to_mapping
from damper_emulator.diagnose.base import (
    ACQUISITION_DELAY,
    BASE_PARAMETERS,
    OIL_COMPRESSIBILITY,
    TERM_PREFIX,
    Record,
    delay_rig,
    model_of,
)
from damper_emulator.diagnose.candidates import Candidate
from damper_emulator.diagnose.discovery import Discovery
from damper_emulator.diagnose.interference import Line
from damper_emulator.diagnose.series import SeriesResult
from damper_emulator.diagnose.statistics import bic_term, delta_bic
from damper_emulator.model.compressible import DamperModel
from damper_emulator.model.discovered import TERM_SIGN
from damper_emulator.params import ModelConfig

#: a candidate must cut the pooled held-out r.m.s. by at least this fraction
MIN_SCORE = 0.05
#: ... and lower the effective BIC on the identification files by at least this much
MAX_DELTA_BIC = -10.0
#: held-out residual r.m.s. / noise level above which structure remains
STRUCTURE_RATIO = 1.5
#: effects that together remove less than this fraction of the held-out residual's
#: structured power while structure remains give ``other``
MIN_EXPLAINED = 0.75
#: the floor: this fraction of the held-out force r.m.s. (the better end of a load cell's
#: and amplifier's 0.5–1 % of reading) ...
FLOOR_FORCE_FRACTION = 0.005
#: ... or this multiple of the held-out noise level, whichever is larger (a residual
#: within it is "within 3× the noise"; a floor of 1 % of the force would hide a 1.5 kg
#: mass on the sport damper's speed series, 3.5× the noise)
FLOOR_NOISE_FACTOR = 3.0
#: forward selection adds at most this many effects
MAX_EFFECTS = 4
#: once an effect is added the search goes on while the held-out residual exceeds this
#: multiple of its noise level (and something is significant): a large first effect
#: must not end the search for the effects it masked, even where what is left is within
#: 1 % of the force
SEARCH_NOISE_FACTOR = 3.0
#: below the floor (an effect in, the search going on for what it masked), an effect is
#: added only where no identification file's own effective ΔBIC (:func:`bic_term`) rises
#: by more than ``−MAX_DELTA_BIC``.  What is left there is small: a second effect of that
#: size has no cause to move the shared parameters the other files fix, where one that
#: stands in for the present effects' form error gains on the files that error is in and
#: loses on the others (``benchmarks/diagnose_bench.py``, ``van:stops_exponential/speeds``:
#: a 48 µs valve lag on top of the end stops, 6.6 % held out and ΔBIC −168 in all, one sine
#: of the speed series +16).  Above the floor a real second effect may: a large one moves
#: the quasi-static test's parameters (``sport:series_compliance>bypass_groove``: +585)
MAX_FILE_BIC_RISE = -MAX_DELTA_BIC
#: from the third round on, only this many candidates are fitted again: those that
#: gained most on the held-out files in the round before (a round is a fit per
#: candidate, and the diagnosis has three minutes on two cores)
LATER_ROUND_CANDIDATES = 4
#: where the rig's delay is significant but an effect gains more without reaching the
#: floor, this many of the runners-up are fitted again with the delay free
CHAIN_RUNNERS = 2
#: a delay fitted with a runner-up counts when it is this many σ from zero
MIN_T_RATIO = 3.0
#: ... and the two together cut the leader's held-out r.m.s. by at least this fraction:
#: they explain most of what the leader leaves.  A delay that stands in for the leader's
#: own kind of effect gives a runner-up a share of it (``benchmarks/diagnose_bench.py``,
#: ``sport:end_stops+series_compliance``: the end stops with a delay 38 % over the
#: compliance); a rig's delay with the effect it hid, most (``sport:cavitation@150Hz``:
#: the cavity with the delay 77 % over free air)
MIN_GAIN_OVER_LEADER = 0.5
#: a file's noise level in the fit's weights is at least this fraction of its force
#: r.m.s. (data without noise would otherwise get an infinite weight)
MIN_NOISE_FRACTION = 1e-3
#: a paper's parameter the joint refit with a discovered term moves by more than this
#: factor from the model it was added to is reported beside the term: the term may then
#: hold part of what the parameter held (a smooth friction term where eq 4's friction
#: fell from 44 N to 6 N is the seal's own friction in another form), and the two are
#: read together.  It is a report, not a test: a valve constant moved ×3.6 beside that
#: friction term, a trade within the fit.
TERM_MOVED_FACTOR = 2.0
#: eq 4's friction ``F_fr sgn(ẋ)`` [N] (a paper's parameter, :data:`BASE_PARAMETERS`)
FRICTION = "friction_force_n"
#: a term's smooth sign ``F tanh(ẋ / v_s)`` is a friction as eq 4's is, and the two are
#: read as one (:class:`TermFriction`): eq 4's friction in a smoother form where the
#: model's gave way to the term (:data:`TERM_MOVED_FACTOR`) and the two together hold
#: what it held, within this fraction of it
FRICTION_TOGETHER_TOLERANCE = 0.25


def moved_beyond_factor(before: float, after: float) -> bool:
    """Whether a value went from ``before`` (> 0) to ``after`` by more than
    :data:`TERM_MOVED_FACTOR` either way."""
    return before > 0.0 and (after * TERM_MOVED_FACTOR < before
                             or after > TERM_MOVED_FACTOR * before)


@dataclass(frozen=True)
class TermFriction:
    """A discovered term's smooth-sign part read with eq 4's friction: the friction in the
    model the term was added to (``before``) and refitted with the term (``after``), and
    the term's ``F tanh(ẋ / v_s)`` (``term`` [N], ``sign_m_s`` = ``v_s`` [m/s])."""

    before: float
    after: float
    term: float
    sign_m_s: float

    @property
    def together(self) -> float:
        """The friction of the two [N] at speed (where ``tanh`` is 1)."""
        return self.after + self.term

    @property
    def in_its_place(self) -> bool:
        """Eq 4's friction in another form: the model's gave way to the term (moved by
        more than :data:`TERM_MOVED_FACTOR`), and the two together hold what it held
        (within :data:`FRICTION_TOGETHER_TOLERANCE`)."""
        return (moved_beyond_factor(self.before, self.after)
                and abs(self.together / self.before - 1.0) <= FRICTION_TOGETHER_TOLERANCE)

    def reading(self) -> str:
        """In words, for the report and the JSON."""
        if self.in_its_place:
            return ("eq 4's friction in another form: a sign smoothed over "
                    f"{1e3 * self.sign_m_s:.3g} mm/s where eq 4 switches at ẋ = 0")
        return "a friction beside eq 4's"

    def to_json(self) -> dict[str, Any]:
        return {"parameter": FRICTION, "before": self.before, "after": self.after,
                "term": self.term, "sign_m_s": self.sign_m_s, "together": self.together,
                "in_its_place": self.in_its_place, "reading": self.reading()}


def _sd(x: float | None) -> float | None:
    """A σ for the JSON: ``None`` where undetermined (infinite: ``Space.std``), as JSON
    has no infinity."""
    return x if x is not None and math.isfinite(x) else None


def _sds(sd: Mapping[str, float]) -> dict[str, float | None]:
    return {k: _sd(v) for k, v in sd.items()}


def _damper(values: Mapping[str, float]) -> dict[str, float]:
    """``values`` without the estimated chain's delay (the JSON's ``acquisition``: the
    rig's, not the damper's) and a discovered term's coefficients (its ``discovered``)."""
    return {k: v for k, v in values.items()
            if k != ACQUISITION_DELAY and not k.startswith(TERM_PREFIX)}


def estimated_reading(tau: float) -> str:
    """What an estimated delay ``tau`` [s] of the force can be, in words."""
    if tau > 0.0:
        fc = estimated_rig(tau).force.cutoff_hz
        return (f"the force is recorded {1e3 * tau:.3g} ms late against the displacement: "
                f"a 2nd-order Butterworth load-cell filter at {fc:.3g} Hz, or a skew, or "
                "both (within the tests' band they differ by (f/f_c)^4)")
    if tau < 0.0:
        return (f"the force is recorded {-1e3 * tau:.3g} ms early against the "
                "displacement: a skew, or a filter on the displacement channel")
    return "no delay between force and displacement"


def noise_level(r: np.ndarray) -> float:
    """Robust standard deviation of the white part of ``r`` [N]: the median absolute
    deviation of the first differences, ``1.4826 MAD(Δr) / √2`` (a smooth model error
    hardly changes from one sample to the next; white noise of σ gives differences of
    σ√2)."""
    if r.size < 3:
        return 0.0
    d = np.diff(r)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def _mean_square(residuals: Sequence[np.ndarray]) -> float:
    """Mean square over all samples of ``residuals`` [N²]."""
    n = sum(r.size for r in residuals)
    return sum(float(np.dot(r, r)) for r in residuals) / max(n, 1)


def _noise_square(residuals: Sequence[np.ndarray]) -> float:
    """Square of the pooled noise level of ``residuals`` (each file's :func:`noise_level`,
    weighted by its samples) [N²]."""
    n = sum(r.size for r in residuals)
    return sum(noise_level(r) ** 2 * r.size for r in residuals) / max(n, 1)


def pooled_rms(residuals: Sequence[np.ndarray]) -> float:
    return math.sqrt(_mean_square(residuals))


def structure_ratio(residuals: Sequence[np.ndarray]) -> float:
    """Pooled r.m.s. over the pooled noise level of ``residuals`` (1 for white noise)."""
    noise = math.sqrt(_noise_square(residuals))
    return pooled_rms(residuals) / noise if noise > 0 else math.inf


def explained_fraction(before: Sequence[np.ndarray], after: Sequence[np.ndarray]) -> float:
    """Fraction of the structured power (mean square less the noise level's square, pooled)
    of residuals ``before`` that is gone ``after`` (the same files); noise levels from
    ``after``."""
    noise2 = _noise_square(after)
    p0 = _mean_square(before) - noise2
    p1 = _mean_square(after) - noise2
    if p0 <= 0.0:
        return 0.0
    return 1.0 - max(p1, 0.0) / p0


def floor_level(held: Sequence[Record], residuals: Sequence[np.ndarray]) -> tuple[float, float]:
    """``(floor, noise)`` [N] of the held-out files for the model with ``residuals``:
    ``max(FLOOR_FORCE_FRACTION × pooled force r.m.s., FLOOR_NOISE_FACTOR × pooled noise
    level)`` and that noise level."""
    noise = math.sqrt(_noise_square(residuals))
    force_rms = pooled_rms([rec.data.force[rec.start:] for rec in held])
    return max(FLOOR_FORCE_FRACTION * force_rms, FLOOR_NOISE_FACTOR * noise), noise


@dataclass
class StepFit:
    """One fitted model of a diagnosis (the output of
    :func:`~damper_emulator.diagnose.tasks.run_fit_task`), scored
    against the model it was fitted on top of."""

    cfg: ModelConfig
    candidates: list[Candidate]
    out: dict[str, Any]
    #: held-out gain against the reference, ΔBIC, significant
    score: float = 0.0
    delta_bic: float = 0.0
    significant: bool = False
    #: the reference's held-out r.m.s. per file [N] (the model before this fit)
    rms_held_out_before: dict[str, float] = field(default_factory=dict)
    #: the identification file this fit made worse beyond ``MAX_FILE_BIC_RISE`` and its
    #: effective ΔBIC, where that refused it (:meth:`refuse_trade`)
    trades: tuple[str, float] | None = None

    @property
    def candidate(self) -> Candidate | None:
        """The effect this fit added (``None`` for a refit of the present model)."""
        return self.candidates[-1] if self.out["effect"] is not None else None

    @property
    def _added(self) -> Candidate:
        """:attr:`candidate` of a fit that added an effect (every step, ranked fit and
        ``closest`` of a diagnosis: never a refit, whose ``None`` mypy cannot rule out)."""
        return cast(Candidate, self.candidate)

    @property
    def effects(self) -> list[str]:
        return list(self.out["effects"])

    @property
    def values(self) -> dict[str, float]:
        """The added effect's fitted parameters (by candidate parameter name)."""
        return self.out["values"][-1] if self.out["effect"] is not None else {}

    @property
    def std(self) -> dict[str, float]:
        return self.out["std"][-1] if self.out["effect"] is not None else {}

    @property
    def extension(self) -> dict[str, float]:
        c = self.candidate
        return {k: float(v) for k, v in c.fields(self.values).items()} if c else {}

    @property
    def rms_fit(self) -> dict[str, float]:
        return {k: v["rms"] for k, v in self.out["fit"].items()}

    @property
    def rms_held_out(self) -> dict[str, float]:
        return {k: v["rms"] for k, v in self.out["held"].items()}

    @property
    def sse_held(self) -> float:
        sse: float = sum(v["sse"] for v in self.out["held"].values())
        return sse

    @property
    def seconds(self) -> float:
        return float(self.out["seconds"])

    @property
    def evaluations(self) -> int:
        return int(self.out["evaluations"])

    def model(self) -> DamperModel:
        return model_of(self.cfg, self.out["base_values"],
                        list(zip(self.candidates, self.out["values"])))

    @property
    def rig(self) -> RigParams | None:
        """The measurement chain estimated with this fit (``None``: given, or none)."""
        return delay_rig(self.out["base_values"])

    def residuals(self, records: Sequence[Record]) -> list[np.ndarray]:
        """The residual of this fit's model through its chain on each of ``records``."""
        model, rig = self.model(), self.rig
        return [r.residual(model, rig=rig) for r in records]

    def replaces(self, step: StepFit) -> StepFit:
        """This fit (``step``'s model with the rig's delay freed) in the place of
        ``step``: its effects, and its score (the delay is the rig's, not a gain of an
        effect)."""
        for attr in ("score", "delta_bic", "significant", "rms_held_out_before"):
            setattr(self, attr, getattr(step, attr))
        self.candidates = list(step.candidates)
        # the step's added effect stays its: the chain fit itself added none
        self.out = {**self.out, "effect": step.out["effect"]}
        return self

    def score_against(self, ref: StepFit, floor_reached: bool) -> None:
        """Held-out gain and ΔBIC against ``ref`` (module docstring, steps 4–6)."""
        self.rms_held_out_before = ref.rms_held_out
        sse0 = ref.sse_held
        self.score = 1.0 - math.sqrt(self.sse_held / sse0) if sse0 > 0 else 0.0
        k = (sum(len(c.parameters) for c in self.candidates)
             - sum(len(c.parameters) for c in ref.candidates)
             # the estimated chain's delay and the force's scale, where this fit has
             # them and ``ref`` not
             + sum((p in self.out["base_values"]) - (p in ref.out["base_values"])
                   for p in (ACQUISITION_DELAY, OIL_COMPRESSIBILITY)))
        # (rho: lag1, clipped to MAX_RHO)
        self.delta_bic = delta_bic(((f["n"], f["rho"], f["mse"], ref.out["fit"][name]["mse"])
                                    for name, f in self.out["fit"].items()), k)
        self.significant = bool(not floor_reached and self.score >= MIN_SCORE
                                and self.delta_bic <= MAX_DELTA_BIC)

    def worst_file(self, ref: StepFit) -> tuple[str, float]:
        """The identification file this fit made most worse than ``ref`` and its own
        effective ΔBIC (:func:`bic_term`; no parameter counted)."""
        rises = {name: bic_term(f["n"], f["rho"], f["mse"], ref.out["fit"][name]["mse"])
                 for name, f in self.out["fit"].items()}
        name = max(rises, key=lambda k: rises[k])
        return name, rises[name]

    def refuse_trade(self, ref: StepFit) -> tuple[str, float] | None:
        """Below the floor: a significant fit that makes an identification file worse
        than ``ref`` by more than ``MAX_FILE_BIC_RISE`` is not significant (it trades
        files).  The file and its effective ΔBIC where it was refused (also
        :attr:`trades`), else ``None``."""
        if not self.significant:
            return None
        name, rise = self.worst_file(ref)
        if rise <= MAX_FILE_BIC_RISE:
            return None
        self.significant, self.trades = False, (name, rise)
        return self.trades

    def to_json(self) -> dict[str, Any]:
        c = self.candidate
        doc: dict[str, Any] = {
            "effect": c.effect if c else None, "family": c.family if c else None,
            "score": self.score, "significant": self.significant,
            "delta_bic": self.delta_bic, "parameters": self.extension,
            "fitted": ({p.name: {"value": self.values.get(p.name),
                                 "std": _sd(self.std.get(p.name)), "unit": p.unit,
                                 "bounds": [p.lo, p.hi]}
                        for p in c.parameters} if c else {}),
            "rms_fit": self.rms_fit, "rms_held_out": self.rms_held_out,
            "reidentified": bool(self.out.get("reidentified")),
            "friction_factor": self.out.get("friction_factor"),
            "evaluations": self.evaluations, "seconds": round(self.seconds, 2)}
        if c is not None and c.note:
            doc["note"] = c.note
        return {**doc, **self.trade_json()}

    def trade_json(self) -> dict[str, Any]:
        """``trades_file`` (the file and its effective ΔBIC) where :meth:`refuse_trade`
        refused this fit, else nothing."""
        if self.trades is None:
            return {}
        return {"trades_file": {"file": self.trades[0], "delta_bic": self.trades[1]}}


@dataclass(frozen=True)
class Pruned:
    """An effect of the forward selection tried away once the search ended (backward
    elimination, :meth:`~damper_emulator.diagnose.rounds.LibraryRounds.prune`): the held-out
    gain and ΔBIC of the effects with it against them refitted without it, whether it
    went, and the held-out r.m.s. per file without it [N]."""

    effect: str
    family: str
    gain: float
    delta_bic: float
    went: bool
    rms_held_out_without: dict[str, float]

    def to_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "family": self.family, "held_out_gain": self.gain,
                "delta_bic": self.delta_bic, "went": self.went,
                "rms_held_out_without": self.rms_held_out_without}


@dataclass
class Diagnosis:
    """Result of :func:`~damper_emulator.diagnose.selection.diagnose`; :meth:`to_json` is
    the CONTRACT's ``diagnose`` JSON."""

    family: str
    effect: str | None
    significant: bool
    rms_before: dict[str, float]
    rms_after: dict[str, float]
    #: the first round: every candidate against the refitted paper's model
    ranking: list[StepFit]
    held_out: list[str]
    structure_before: float
    structure_after: float
    seconds: float
    #: the paper's model refitted jointly (the reference of the first round)
    refit: StepFit | None = None
    #: the effects added, in order (each fitted with all before it)
    steps: list[StepFit] = field(default_factory=list)
    #: every round's fits (round 1 = :attr:`ranking`)
    rounds: list[list[StepFit]] = field(default_factory=list)
    #: with ``other``: the first significant effect, which explained too little
    closest: StepFit | None = None
    #: fraction of the refitted model's held-out structured power the effects removed
    explained: float = 0.0
    #: with ``other``: the effects that explained too little, and their pair's gain (the
    #: term discovery may take them back beside its term)
    dropped: list[StepFit] = field(default_factory=list)
    dropped_pair_gain: float | None = None
    #: the first floor and the noise level it was taken from (the refitted model's
    #: held-out residual), and the noise level of what is left after [N]
    floor_n: float = 0.0
    noise_n: float = 0.0
    noise_after_n: float = 0.0
    #: the two effects were found together (step 6's pair): their held-out gain against
    #: the refitted model (neither alone was significant); ``None`` otherwise
    pair_gain: float | None = None
    base_model: DamperModel | None = None
    records: list[Record] = field(default_factory=list)
    #: the term discovered in what the library left (:mod:`.discovery`), if it ran
    discovered: Discovery | None = None
    #: the effects tried away once the forward selection ended, kept or gone
    pruned: list[Pruned] = field(default_factory=list)
    #: the identified model's residual r.m.s. with the rig's findings taken out (lines,
    #: per-file zero and gain) [N]; ``rms_before`` is on the files as recorded
    rms_before_rig: dict[str, float] = field(default_factory=dict)
    #: the lines of interference taken out of the records
    lines: list[Line] = field(default_factory=list)
    #: what moves from file to file over the series
    series: SeriesResult | None = None
    #: what the rig did (``measurement.Finding``), for the JSON's ``measurement``
    measurement: list[Any] = field(default_factory=list)
    #: the force's scale against the oil's stiffness (``scale.ScaleResult``), where the
    #: stage ran
    scale: Any = None
    #: what lies of the held-out residual where the fit files leave an effect's law
    #: undetermined (``undetermined.Undetermined``, one per such effect)
    undetermined: list[Any] = field(default_factory=list)
    #: the model after's own integration error on the records (``numerics.SubstepCheck``)
    numerics: Any = None
    #: the check that made the rounds halve the sub-step (``numerics.SubstepCheck``), or
    #: ``None``
    numerics_refined: Any = None

    @property
    def chosen(self) -> StepFit | None:
        """The first effect added (the main one), ``None`` with ``none``/``other``."""
        return self.steps[0] if self.steps else None

    @property
    def final(self) -> StepFit | None:
        """The model after the diagnosis: the last effect's fit, or the refit."""
        return self.steps[-1] if self.steps else self.refit

    @property
    def term(self) -> Discovery | None:
        """The discovered term in the model after the diagnosis: significant, and refitted
        with the model (``None`` otherwise)."""
        found = self.discovered
        return (found if found is not None and found.significant and found.model is not None
                else None)

    def model_after(self) -> DamperModel:
        """The model after the diagnosis (the identified model when nothing was fitted;
        with a significant discovered term, its joint refit's model holding the term)."""
        term = self.term
        if term is not None and term.model is not None:  # (always, with a term)
            return term.model
        # (base_model: set by diagnose(); None only in a Diagnosis built without it)
        return (self.final.model() if self.final is not None
                else cast(DamperModel, self.base_model))

    def base_after_json(self) -> dict[str, Any] | None:
        """The JSON's ``base_parameters_after``: the paper's parameters of the model after
        the diagnosis (with a significant discovered term, its joint refit's) ± 1σ."""
        found, final = self.term, self.final
        if found is not None:
            values, std = found.base_values, found.base_std
        elif final is not None:
            values, std = final.out["base_values"], final.out["base_std"]
        else:
            return None
        return {"values": _damper(values), "uncertainties": _sds(_damper(std))}

    def term_moved(self) -> dict[str, tuple[float, float]]:
        """The paper's parameters the joint refit with the discovered term moved by more
        than :data:`TERM_MOVED_FACTOR` either way from the model it was added to (the
        library's effects, or the refitted paper's model): ``{path: (before, after)}``,
        empty without a significant term.  Only the paper's parameters
        (:data:`~damper_emulator.diagnose.base.BASE_PARAMETERS`) count: not the fit's
        nuisance parameters, the rig's delay or the term's own coefficients."""
        found, final = self.term, self.final
        if found is None or final is None:
            return {}
        before, after = final.out["base_values"], found.base_values
        moved = {}
        for name in (bp.path for bp in BASE_PARAMETERS):
            b, a = before.get(name), after.get(name)
            if b is not None and a is not None and a > 0.0 and moved_beyond_factor(b, a):
                moved[name] = (float(b), float(a))
        return moved

    def term_friction(self) -> TermFriction | None:
        """The discovered term's smooth-sign part ``F tanh(ẋ / v_s)`` read with eq 4's
        friction (:class:`TermFriction`), ``None`` without a significant refitted term
        that has one."""
        found, final = self.term, self.final
        if found is None or final is None:
            return None
        part = next((k for k, f in enumerate(found.features)
                     if f.index == TERM_SIGN and f.sign_m_s is not None), None)
        before = final.out["base_values"].get(FRICTION)
        after = found.base_values.get(FRICTION)
        if part is None or before is None or after is None:
            return None
        return TermFriction(float(before), float(after), float(found.coefficients[part]),
                            float(cast(float, found.features[part].sign_m_s)))

    def discovered_json(self) -> dict[str, Any] | None:
        """The JSON's ``discovered``: the term, what it took from the model
        (:meth:`term_moved`) and its friction read with eq 4's (:meth:`term_friction`)."""
        if self.discovered is None:
            return None
        friction = self.term_friction()
        return {**self.discovered.to_json(),
                "moved_parameters": {k: {"before": b, "after": a}
                                     for k, (b, a) in self.term_moved().items()},
                "friction_with_model": None if friction is None else friction.to_json()}

    def rig_after(self) -> RigParams | None:
        """The chain estimated with :meth:`model_after` (``None``: given, or none)."""
        if self.term is not None:
            return delay_rig(self.term.base_values)
        return self.final.rig if self.final is not None else None

    def acquisition_json(self) -> dict[str, Any]:
        """The JSON's ``acquisition``: the chain given, or the one estimated with the
        model after the diagnosis (:meth:`rig_after`: its delay ± 1σ), or none."""
        given = self.records[0].data.acquisition if self.records else None
        term, final = self.term, self.final
        values, std = ((term.base_values, term.base_std) if term is not None
                       else (final.out["base_values"], final.out["base_std"])
                       if final is not None else ({}, {}))
        if given is not None or ACQUISITION_DELAY not in values:
            return chain_json(given)
        tau = float(values[ACQUISITION_DELAY])
        rig = estimated_rig(tau)
        return {"source": "estimated", "rig": rig_to_mapping(rig)["rig"],
                "force_delay_s": tau, "force_delay_std_s": _sd(std.get(ACQUISITION_DELAY)),
                "reading": estimated_reading(tau)}

    def effects_json(self) -> list[dict[str, Any]]:
        out = []
        final = cast(StepFit, self.final)  # steps[-1] wherever the loop below runs
        term = self.term
        # the effects' values of the model after: with a term, its joint refit's
        values, stds = ((term.effect_values, term.effect_std)
                        if term is not None and len(term.effect_values) == len(self.steps)
                        else (final.out["values"], final.out["std"]))
        for k, st in enumerate(self.steps):
            c = st._added
            vals = values[k]
            sd = stds[k]
            out.append({"effect": c.effect, "family": c.family,
                        "parameters": {n: float(v) for n, v in c.fields(vals).items()},
                        "fitted": {p.name: {"value": vals[p.name], "std": _sd(sd.get(p.name)),
                                            "unit": p.unit}
                                   for p in c.parameters},
                        "held_out_gain": st.score, "delta_bic": st.delta_bic,
                        "significant": st.significant,
                        "rms_held_out_before": st.rms_held_out_before,
                        "rms_held_out": st.rms_held_out})
        if term is not None and self.steps:
            # the library explained part, the discovered term the rest: both reported
            out.append({"effect": "discovered_term", "family": term.family_hint,
                        "expression": term.expression,
                        "parameters": {k: v for k, v in dataclasses.asdict(
                            term.extension()).items() if v},
                        "held_out_gain": term.held_out_gain, "delta_bic": term.delta_bic,
                        "significant": term.significant, "trust": term.trust(),
                        "rms_held_out": dict(term.rms_held_out_after)})
        return out

    def to_json(self) -> dict[str, Any]:
        chosen = self.chosen
        effects = self.effects_json()
        main = effects[0] if effects else None
        doc: dict[str, Any] = {
            "family": self.family, "effect": self.effect, "significant": self.significant,
            "rms_before": self.rms_before, "rms_after": self.rms_after,
            "candidates": [c.to_json() for c in self.ranking],
            "effects": effects,
            "pruned": [p.to_json() for p in self.pruned],
            "held_out": self.held_out,
            "fit_files": [r.name for r in self.records if not r.held_out],
            "parameters": main["parameters"] if main else None,
            "uncertainties": ({n: f["std"] for n, f in main["fitted"].items()}
                              if main else None),
            "score": (self.pair_gain if self.pair_gain is not None
                      else chosen.score if chosen else None),
            "pair_gain": self.pair_gain,
            "explained_fraction": self.explained,
            "closest": ({"effect": self.closest._added.effect,
                         "effects": self.closest.effects,
                         "family": self.closest._added.family,
                         "score": self.closest.score,
                         "parameters": self.closest.extension}
                        if self.closest else None),
            "refit": ({"rms": {**self.refit.rms_fit, **self.refit.rms_held_out},
                       "parameters": _damper(self.refit.out["base_values"]),
                       "uncertainties": _sds(_damper(self.refit.out["base_std"]))}
                      if self.refit else None),
            "base_parameters_after": self.base_after_json(),
            "rounds": [[{"effect": f.candidate.effect if f.candidate else None,
                         "effects": f.effects,
                         "score": f.score, "delta_bic": f.delta_bic,
                         "significant": f.significant,
                         "reidentified": bool(f.out.get("reidentified")),
                         "friction_factor": f.out.get("friction_factor"),
                         **f.trade_json()} for f in rnd]
                       for rnd in self.rounds],
            "acquisition": self.acquisition_json(),
            "discovered": self.discovered_json(),
            "rms_before_without_rig": self.rms_before_rig,
            "measurement": [f.to_json() for f in self.measurement],
            "drift": ([d.to_json(self.series.reference) for d in self.series.taken]
                      if self.series is not None else []),
            "series": ({"positions": self.series.positions, "tried": self.series.tried}
                       if self.series is not None else None),
            "scale": self.scale.to_json() if self.scale is not None else None,
            "undetermined": [u.to_json() for u in self.undetermined],
            "numerics": ({**self.numerics.to_json(), "refined_from": (
                self.numerics_refined.to_json() if self.numerics_refined is not None
                else None)} if self.numerics is not None else None),
            "structure_ratio_before": self.structure_before,
            "structure_ratio_after": self.structure_after,
            "floor_N": self.floor_n, "noise_N": self.noise_n,
            "noise_after_N": self.noise_after_n,
            "thresholds": {"min_score": MIN_SCORE, "max_delta_bic": MAX_DELTA_BIC,
                           "structure_ratio": STRUCTURE_RATIO,
                           "min_explained": MIN_EXPLAINED,
                           "floor_force_fraction": FLOOR_FORCE_FRACTION,
                           "floor_noise_factor": FLOOR_NOISE_FACTOR,
                           "max_effects": MAX_EFFECTS,
                           "search_noise_factor": SEARCH_NOISE_FACTOR},
            "seconds": round(self.seconds, 2)}
        return doc
