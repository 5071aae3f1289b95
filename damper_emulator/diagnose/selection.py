"""Which missing effects explain the residual: re-identify the damper with each candidate
inside the model, score on held-out data, add effects by forward selection, or say
``none`` / ``other``.

Procedure (:func:`diagnose`):

1. **Before.**  The identified model (``identify``'s result, the user's parameters) is
   simulated over every file (as ``validate`` does): the residuals "before".
2. **Refit.**  The paper's model alone is fitted again, jointly over the identification
   files (quasi-static + chirp) simulated whole (:func:`damper_emulator.diagnose.joint.
   joint_fit`): the reference every candidate has to beat.  ``identify``'s staged fits are
   not the least-squares optimum of the simulated model; without this step that gain
   would be credited to whichever effect came first.
3. **Candidates, jointly.**  Each candidate effect (:mod:`damper_emulator.diagnose.
   candidates`) is pre-fitted on top of the present model and then fitted *together with*
   every paper's parameter and every effect already accepted.  The cost is
   ``Σ_f mean_f((F_sim − F_meas)²) / σ_f²``, each file in units of its own noise level
   ``σ_f`` (:func:`noise_level` of the identified model's residual): a file already at its
   noise counts as much as one far from it, and none stops the fit early.
4. **Score** on the held-out files (the validation sines), never seen by a fit:
   ``gain = 1 − √(Σ SSE_candidate / Σ SSE_reference)``, the pooled r.m.s. reduction
   against the present model.
5. **Penalise** the added parameters with the Bayesian information criterion on the
   identification files, ``ΔBIC = Σ_f n_f,eff ln(MSE_f / MSE_f,ref) + k ln N_eff``, each
   file's sample count reduced to the effective number of independent samples of an AR(1)
   residual, ``n_eff = n (1 − ρ)/(1 + ρ)`` (ρ the lag-1 autocorrelation of the candidate's
   residual: a dyno record's residual is never white, and the plain BIC would take 40,000
   correlated samples as 40,000 pieces of evidence).
6. **Forward selection.**  A candidate is *significant* when the present model's held-out
   residual is above the engineering floor (below), its gain is at least
   :data:`MIN_SCORE` and ``ΔBIC ≤`` :data:`MAX_DELTA_BIC`.  The one with the largest gain
   is added, its joint fit becomes the present model, and the remaining candidates are
   fitted again on top of it (step 3); this repeats until none is significant, the floor
   is reached, or :data:`MAX_EFFECTS` are in.
   **A pair** when nothing is significant alone but structure above the floor remains:
   the candidate with the most evidence on the identification files (the lowest ΔBIC,
   at most ``MAX_DELTA_BIC``) is fitted with each other candidate, and a pair that is
   significant against the refitted model (the same two tests, its parameters all
   counted) adds both.  Two effects that the identification files confound are found
   this way: on a chirp whose temperature rises with its frequency, a bypass groove fits
   the identification files far better (ΔBIC −8257) but extrapolates badly to the hotter
   held-out sines (gain −36 %) until the oil's viscosity–temperature law is fitted with
   it (together +96 %).
7. **Answer.**  No effect added: ``none`` when the refitted model's held-out residual is
   within the floor or has no structure (r.m.s. at most :data:`STRUCTURE_RATIO` × its
   noise level), else ``other``.  Effects added: the first (largest) names the family,
   unless together they remove less than :data:`MIN_EXPLAINED` of the refitted model's
   held-out structured power (:func:`explained_fraction`) while structure above the floor
   remains: then ``other``, the first as the closest family, nothing added.

**The rig's delay** (no chain given: ``docs/diagnose.md``, "The measurement chain")
competes in every round as the chain candidate: taken when it gains at least as much as
every significant effect; taken with a runner-up where an effect gains more but leaves
structure and the runner-up with the delay gains significantly more than it; else tried
once more on top of the effects added.

**The floor** ("small in engineering terms") is the larger of :data:`FLOOR_FORCE_FRACTION`
of the held-out force r.m.s. and :data:`FLOOR_NOISE_FACTOR` × the held-out noise level.
1 % of the force is the accuracy of a dyno's force channel (load cells and their
amplifiers are specified to 0.5–1 % of reading) and the spread between repeated runs; a
model within it has nothing left to explain that the instrument could vouch for.  A
residual within twice its white-noise level carries at most 3/4 of its power in structure
of r.m.s. ≤ √3 σ, below anything a fit of one more effect can separate from the noise on
a few sine cycles.

Other thresholds: ``MIN_SCORE`` = 5 %: on data without an extra effect (noise only) the
best candidate's held-out gain stayed below 0.5 % (``docs/diagnose.md``);
``MAX_DELTA_BIC`` = −10 is "very strong" evidence on the Kass & Raftery (1995) scale;
``STRUCTURE_RATIO`` = 1.5: white noise gives 1.0 ± 0.02 on these record lengths, and a
residual 1.5× its noise level carries more than half its power in structure
(1 − 1/1.5² = 56 %).

The fits of a round are independent tasks (:class:`FitTask`, run by :func:`run_fit_task`)
submitted to one :class:`concurrent.futures.Executor`: a local process pool by default, or
any other, e.g. a Dask cluster's ``distributed.Client(...).get_executor()``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import Executor, as_completed
from dataclasses import dataclass, field
from typing import Any, TypeVar, cast

import numpy as np
from threadpoolctl import threadpool_limits

from damper_emulator.acquisition.chain import ESTIMATED_DELAY_START_S, chain_json, estimated_rig
from damper_emulator.acquisition.rig import RigParams, rig_to_mapping
from damper_emulator.diagnose.candidates import Candidate
from damper_emulator.diagnose.candidates import candidates as make_candidates
from damper_emulator.diagnose.discovery import Discovery, discover, refit_with_term
from damper_emulator.diagnose.joint import (
    ACQUISITION_DELAY,
    JOINT_NFEV,
    TERM_PREFIX,
    Record,
    base_parameters,
    chain_unknown,
    delay_rig,
    delta_bic,
    joint_fit,
    lag1,
    make_record,
    model_of,
)
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import ModelConfig
from damper_emulator.validation import rms

__all__ = ["Diagnosis", "FitTask", "Record", "StepFit", "diagnose", "run_fit_task",
           "noise_level", "structure_ratio", "explained_fraction",
           "make_record", "weigh_effects"]

#: a candidate must cut the pooled held-out r.m.s. by at least this fraction
MIN_SCORE = 0.05
#: ... and lower the effective BIC on the identification files by at least this much
MAX_DELTA_BIC = -10.0
#: held-out residual r.m.s. / noise level above which structure remains
STRUCTURE_RATIO = 1.5
#: effects that together remove less than this fraction of the held-out residual's
#: structured power while structure remains give ``other``
MIN_EXPLAINED = 0.75
#: the floor: this fraction of the held-out force r.m.s. ...
FLOOR_FORCE_FRACTION = 0.01
#: ... or this multiple of the held-out noise level, whichever is larger
FLOOR_NOISE_FACTOR = 2.0
#: forward selection adds at most this many effects
MAX_EFFECTS = 2
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

Progress = Callable[[str], None] | None

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


@dataclass(frozen=True)
class FitTask:
    """One independent fit of a diagnosis, in plain picklable values: the identified
    configuration, the files, the cost weights, the present model (its paper's parameters
    and the effects ``accepted`` with their values) and the candidate ``effect`` to add
    (``None``: refit the present model alone)."""

    cfg: ModelConfig
    fit: tuple[MeasuredData, ...]
    held: tuple[MeasuredData, ...]
    weights: tuple[float, ...]
    base_values: Mapping[str, float]
    accepted: tuple[tuple[str, Mapping[str, float]], ...]
    effect: str | None
    nfev: int = JOINT_NFEV
    #: the first this many ``fit`` files are quasi-static tests, the others chirps
    n_quasi_static: int = 1
    #: the candidate's own fit of the round before (its paper's parameters, and its
    #: effects' values by name): the start of the other order (``joint_fit``)
    alternative: tuple[Mapping[str, float], Mapping[str, Mapping[str, float]]] | None = None
    #: the chain candidate: the present model with the estimated chain's delay added
    #: (``effect`` is ``None``)
    chain: bool = False


#: BLAS threads a fit task runs with (:func:`run_fit_task`).  The fits are the parallel
#: work, one task per core; OpenBLAS would otherwise start a pool of one thread per core in
#: every worker, and those threads (which spin before they sleep) compete with the other
#: worker's fit: with two processes on two cores every task runs about 1.4× longer than
#: alone; with one BLAS thread per task the diagnosis takes about a third less
#: (benchmarks/diagnose_bench.py).  Dask's nanny sets the same for its workers
#: (``OPENBLAS_NUM_THREADS=1``, ``distributed.nanny.pre-spawn-environ``).  It also keeps
#: the fits' sums independent of the machine's core count (threaded BLAS splits them by
#: thread, and a fit's path can follow the last bits: docs/diagnose.md).
FIT_BLAS_THREADS = 1


def run_fit_task(task: FitTask) -> dict[str, Any]:
    """Run one :class:`FitTask` (in any process, with :data:`FIT_BLAS_THREADS` BLAS
    threads): the joint fit and the plain figures the selection needs (per file: MSE,
    lag-1 autocorrelation and samples of the fit files, SSE of the held-out files)."""
    with threadpool_limits(limits=FIT_BLAS_THREADS, user_api="blas"):
        return _run_fit_task(task)


def _run_fit_task(task: FitTask) -> dict[str, Any]:
    t0 = time.perf_counter()
    fit = [make_record(d, False) for d in task.fit]
    held = [make_record(d, True) for d in task.held]
    cands = {c.effect: c for c in make_candidates(task.cfg, task.fit)}
    accepted = [(cands[e], v) for e, v in task.accepted]
    cand = cands[task.effect] if task.effect is not None else None
    base_values = dict(task.base_values)
    if task.chain:
        base_values.setdefault(ACQUISITION_DELAY, ESTIMATED_DELAY_START_S)
    jf = joint_fit(task.cfg, fit, task.weights, base_values, accepted, cand, task.nfev,
                   task.n_quasi_static, task.alternative)
    order = [c for c, _ in accepted] + ([cand] if cand is not None else [])
    model = jf.model(task.cfg, order)
    rig = delay_rig(jf.base_values)
    fit_res = [r.residual(model, rig=rig) for r in fit]
    held_res = [r.residual(model, rig=rig) for r in held]
    return {"effect": task.effect, "chain": task.chain,
            "effects": [c.effect for c in order],
            "base_values": {k: float(v) for k, v in jf.base_values.items()},
            "base_std": {k: float(v) for k, v in jf.base_std.items()},
            "values": [{k: float(v) for k, v in vals.items()} for vals in jf.values],
            "std": [{k: float(v) for k, v in sd.items()} for sd in jf.std],
            "fit": {r.name: {"mse": float(np.mean(x * x)), "rho": lag1(x), "n": int(x.size),
                             "rms": rms(x)} for r, x in zip(fit, fit_res)},
            "held": {r.name: {"sse": float(np.dot(x, x)), "rms": rms(x)}
                     for r, x in zip(held, held_res)},
            "reidentified": jf.reidentified, "friction_factor": jf.friction_factor,
            "evaluations": jf.evaluations, "seconds": time.perf_counter() - t0}


@dataclass
class StepFit:
    """One fitted model of a diagnosis (the output of :func:`run_fit_task`), scored
    against the model it was fitted on top of."""

    cfg: ModelConfig
    candidates: list[Candidate]
    out: dict[str, Any]
    #: held-out gain against the reference, ΔBIC, significant
    score: float = 0.0
    delta_bic: float = 0.0
    significant: bool = False

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
        for attr in ("score", "delta_bic", "significant"):
            setattr(self, attr, getattr(step, attr))
        self.candidates = list(step.candidates)
        # the step's added effect stays its: the chain fit itself added none
        self.out = {**self.out, "effect": step.out["effect"]}
        return self

    def score_against(self, ref: StepFit, floor_reached: bool) -> None:
        """Held-out gain and ΔBIC against ``ref`` (module docstring, steps 4–6)."""
        sse0 = ref.sse_held
        self.score = 1.0 - math.sqrt(self.sse_held / sse0) if sse0 > 0 else 0.0
        k = (sum(len(c.parameters) for c in self.candidates)
             - sum(len(c.parameters) for c in ref.candidates)
             # the estimated chain's delay, where this fit has it and ``ref`` not
             + (ACQUISITION_DELAY in self.out["base_values"])
             - (ACQUISITION_DELAY in ref.out["base_values"]))
        # (rho: lag1, clipped to MAX_RHO)
        self.delta_bic = delta_bic(((f["n"], f["rho"], f["mse"], ref.out["fit"][name]["mse"])
                                    for name, f in self.out["fit"].items()), k)
        self.significant = bool(not floor_reached and self.score >= MIN_SCORE
                                and self.delta_bic <= MAX_DELTA_BIC)

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
        return doc


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_json` is the CONTRACT's ``diagnose`` JSON."""

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
    floor_n: float = 0.0
    noise_n: float = 0.0
    #: the two effects were found together (step 6's pair): their held-out gain against
    #: the refitted model (neither alone was significant); ``None`` otherwise
    pair_gain: float | None = None
    base_model: DamperModel | None = None
    records: list[Record] = field(default_factory=list)
    #: the term discovered in what the library left (:mod:`.discovery`), if it ran
    discovered: Discovery | None = None

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
        for k, st in enumerate(self.steps):
            c = st._added
            vals = final.out["values"][k]
            sd = final.out["std"][k]
            out.append({"effect": c.effect, "family": c.family,
                        "parameters": {n: float(v) for n, v in c.fields(vals).items()},
                        "fitted": {p.name: {"value": vals[p.name], "std": _sd(sd.get(p.name)),
                                            "unit": p.unit}
                                   for p in c.parameters},
                        "held_out_gain": st.score, "delta_bic": st.delta_bic,
                        "significant": st.significant,
                        "rms_held_out": st.rms_held_out})
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
                         "friction_factor": f.out.get("friction_factor")} for f in rnd]
                       for rnd in self.rounds],
            "acquisition": self.acquisition_json(),
            "discovered": self.discovered.to_json() if self.discovered is not None else None,
            "structure_ratio_before": self.structure_before,
            "structure_ratio_after": self.structure_after,
            "floor_N": self.floor_n, "noise_N": self.noise_n,
            "thresholds": {"min_score": MIN_SCORE, "max_delta_bic": MAX_DELTA_BIC,
                           "structure_ratio": STRUCTURE_RATIO,
                           "min_explained": MIN_EXPLAINED,
                           "floor_force_fraction": FLOOR_FORCE_FRACTION,
                           "floor_noise_factor": FLOOR_NOISE_FACTOR,
                           "max_effects": MAX_EFFECTS},
            "seconds": round(self.seconds, 2)}
        return doc


#: the chain candidate's place in a round's list of effects (:func:`diagnose`)
CHAIN = "(the rig's delay)"

#: a task of the pool and its result
_T = TypeVar("_T")
_R = TypeVar("_R")


class _LocalPool:
    """The default executor: a fork-based process pool (the workers inherit the compiled
    kernels) of ``jobs`` processes, or this process for one."""

    def __init__(self, jobs: int):
        self.jobs = jobs
        self.pool: Executor | None = None

    def __enter__(self) -> _LocalPool:
        if self.jobs > 1:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            self.pool = ProcessPoolExecutor(self.jobs,
                                            mp_context=multiprocessing.get_context("fork"))
        return self

    def __exit__(self, *exc: object) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)

    def map_unordered(self, fn: Callable[[_T], _R], tasks: Iterable[_T]
                      ) -> Iterator[tuple[int, _R]]:
        if self.pool is None:
            for i, t in enumerate(tasks):
                yield i, fn(t)
            return
        yield from _unordered(self.pool, fn, tasks)


def _unordered(executor: Executor, fn: Callable[[_T], _R], tasks: Iterable[_T]
               ) -> Iterator[tuple[int, _R]]:
    futures = {executor.submit(fn, t): i for i, t in enumerate(tasks)}
    for fut in as_completed(futures):
        yield futures[fut], fut.result()


def weigh_effects(refit: StepFit, ref_held: Sequence[np.ndarray], steps: list[StepFit],
                  held: Sequence[Record], floor: float, pair_gain: float | None,
                  min_explained: float = MIN_EXPLAINED,
                  structure: float = STRUCTURE_RATIO
                  ) -> tuple[list[StepFit], StepFit | None, float, float | None]:
    """Step 7 on the effects ``steps`` added (``pair_gain``: found as a pair): whether
    they explain enough of the refitted model's held-out residual ``ref_held`` (on the
    records ``held``).

    Returns ``(steps, closest, explained, pair_gain)``: ``steps`` unchanged, unless they
    remove less than ``min_explained`` of the structured power while the residual stays
    above ``floor`` and above ``structure`` × its noise level; then no step, and the
    closest is the first step (for a pair, the pair's fit, scored against ``refit``)."""
    if not steps:
        return steps, None, 0.0, pair_gain
    final_held = steps[-1].residuals(held)
    explained = explained_fraction(ref_held, final_held)
    if (explained >= min_explained or structure_ratio(final_held) <= structure
            or pooled_rms(final_held) <= floor):
        return steps, None, explained, pair_gain
    closest = steps[0]
    if pair_gain is not None:  # the pair's fit, scored as a pair
        closest = steps[-1]
        closest.score_against(refit, False)
    return [], closest, explained, None


def _discover(diag: Diagnosis, base: DamperModel, fit: Sequence[Record],
              held: Sequence[Record], weights: Sequence[float], floor: float,
              n_quasi_static: int, nfev: int, say: Callable[[str], None]) -> Discovery:
    """Step 8: the term discovery on what the library left (module
    :mod:`damper_emulator.diagnose.discovery`), from the model after the diagnosis and
    from the identified model (whose parameters no fit has bent towards the effect: a
    refit of the paper's model alone gave a 6 kg inertia's chirp 70 N of error on the
    quasi-static test), and from the latter with the local dictionary too (the zones for
    the damping polynomials), the one whose term gains more on the held-out files, as the
    candidates compete; then the term fitted jointly with the model after the
    diagnosis."""
    final = diag.final
    after_model, after_rig = diag.model_after(), diag.rig_after()
    say("discovery: what the library left, regressed on the dictionary of motion and "
        "model states")
    found = discover(after_model, after_rig, fit, held, weights, floor,
                     diag.structure_after, STRUCTURE_RATIO, MIN_SCORE, MAX_DELTA_BIC, say)
    if not found.ran or final is None:
        return found
    alt = discover(base, after_rig, fit, held, weights, 0.0, math.inf, STRUCTURE_RATIO,
                   MIN_SCORE, MAX_DELTA_BIC, say, dictionaries=(False, True))
    if alt.features and (not found.features or alt.held_out_gain > found.held_out_gain):
        say("discovery: the term found on the identified model's residual is taken")
        found = alt
    if not found.features:
        return found
    accepted = list(zip(final.candidates, final.out["values"]))
    return refit_with_term(found, diag.base_model.cfg if diag.base_model else base.cfg,
                           final.out["base_values"], accepted, fit, held, weights,
                           final.residuals(fit), final.residuals(held), MIN_SCORE,
                           MAX_DELTA_BIC, n_quasi_static, nfev, say)


def diagnose(base: DamperModel, fit_data: Sequence[MeasuredData],
             held_out_data: Sequence[MeasuredData], effects: Sequence[str] | None = None,
             progress: Progress = None, jobs: int | None = None,
             executor: Executor | None = None, max_effects: int = MAX_EFFECTS,
             nfev: int = JOINT_NFEV, n_quasi_static: int = 1,
             discovery: bool = True) -> Diagnosis:
    """Diagnose the residual of ``base`` (the identified model) on ``fit_data``
    (quasi-static and chirp: fitted) and ``held_out_data`` (scored only), with the
    candidates ``effects`` (default: all); module docstring.  The first ``n_quasi_static``
    files of ``fit_data`` are quasi-static tests, the others chirps (the re-identification
    of a local effect needs to know which).

    ``discovery``: regress what the library leaves on the dictionary of
    :mod:`damper_emulator.diagnose.discovery` (step 8).

    The fits run on ``executor`` (any :class:`concurrent.futures.Executor`, e.g. a Dask
    client's ``get_executor()``) or, without one, in ``jobs`` forked processes (default
    one: in this process).

    Raises
    ------
    ValueError
        One line: no held-out file, duplicate file names, or a file the model cannot
        simulate (naming it).
    """
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    if not fit_data or not held_out_data:
        raise UserError("diagnose needs identification files (quasi-static, chirp) and at "
                         "least one held-out validation file")
    names = [d.name or d.path for d in (*fit_data, *held_out_data)]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise UserError(f"two data files share the name {dup[0]!r}; names must differ")
    if base.cfg.damper.extensions is not None:
        raise UserError("diagnose needs the identified model without damper.extensions")
    cfg = base.cfg
    records = ([make_record(d, False) for d in fit_data]
               + [make_record(d, True) for d in held_out_data])
    fit = [r for r in records if not r.held_out]
    held = [r for r in records if r.held_out]
    base_res = {r.name: r.residual(base) for r in records}
    rms_before = {r.name: rms(base_res[r.name]) for r in records}
    weights = []
    for r in fit:
        force_rms = rms(r.data.force[r.start:])
        sigma = max(noise_level(base_res[r.name]), MIN_NOISE_FRACTION * force_rms, 1e-9)
        weights.append(1.0 / (math.sqrt(r.counted) * sigma))
    say("identified model: held-out r.m.s. "
        + ", ".join(f"{r.name} {rms_before[r.name]:.1f} N" for r in held))
    cands = make_candidates(cfg, [r.data for r in fit], effects)
    by_effect = {c.effect: c for c in cands}
    base_values = {p.name: p.start for p in base_parameters(cfg, [r.data for r in fit])}
    estimate = chain_unknown([r.data for r in records])
    if estimate:
        say("no measurement chain given (--rig): the rig's delay of the force against the "
            "displacement competes with the effects (the chain candidate)")

    def task(present: StepFit | None, effect: str | None,
             before: StepFit | None = None) -> FitTask:
        acc: tuple[tuple[str, Mapping[str, float]], ...]
        if present is None:
            bv, acc = base_values, ()
        else:
            bv = present.out["base_values"]
            acc = tuple(zip(present.effects, present.out["values"]))
        # an effect that replaces a paper's parameter leaves it at the identified value
        bv = {**base_values, **bv}
        alt = (None if before is None else
               (before.out["base_values"], dict(zip(before.effects, before.out["values"]))))
        chain = effect == CHAIN
        return FitTask(cfg, tuple(r.data for r in fit), tuple(r.data for r in held),
                       tuple(weights), bv, acc, None if chain else effect, nfev,
                       n_quasi_static, alt, chain)

    def step_fit(present: StepFit | None, out: dict[str, Any]) -> StepFit:
        order = ([] if present is None else list(present.candidates))
        if out["effect"] is not None:
            order.append(by_effect[out["effect"]])
        return StepFit(cfg, order, out)

    jobs = max(1, int(jobs or 1))
    pair_gain: float | None = None
    rounds: list[list[StepFit]] = []
    steps: list[StepFit] = []
    with _LocalPool(jobs if executor is None else 1) as local:
        def run(present: StepFit | None, effects_: Sequence[str | None], label: str,
                before: Mapping[str, StepFit] | None = None) -> list[StepFit]:
            # the longest fits first (a round ends with its last fit: better several short
            # ones than one long one alone on a worker)
            order = sorted(range(len(effects_)), key=lambda i: -(
                by_effect[e].relative_cost if (e := effects_[i]) in by_effect else 0))
            tasks = [task(present, e, (before or {}).get(e) if e in by_effect else None)
                     for e in (effects_[i] for i in order)]
            out: list[StepFit | None] = [None] * len(tasks)
            it = (_unordered(executor, run_fit_task, tasks) if executor is not None
                  else local.map_unordered(run_fit_task, tasks))
            for n_done, (i, res) in enumerate(it, 1):
                out[order[i]] = step_fit(present, res)
                e = res["effect"] or ("the rig's delay" if res["chain"]
                                      else "present model alone")
                say(f"{label} [{n_done}/{len(tasks)}] {e}: held-out r.m.s. "
                    + ", ".join(f"{v['rms']:.1f}" for v in res["held"].values())
                    + f" N ({res['evaluations']} simulations, {res['seconds']:.1f} s; "
                    f"{time.perf_counter() - t_start:.0f} s into the diagnosis)")
            return cast("list[StepFit]", out)  # every task has filled its slot

        def pair_search(ref: StepFit, fits: list[StepFit]) -> list[StepFit] | None:
            """Step 6's pair: the fit with the most evidence on the identification files
            (the lowest ΔBIC, at most ``MAX_DELTA_BIC``) fitted with each other candidate,
            each pair scored against ``ref``; ``[lead, partner]`` (the partner scored
            against the lead, as a second step is) or ``None``."""
            if len(fits) < 2:
                return None
            lead = min(fits, key=lambda f: f.delta_bic)
            if lead.delta_bic > MAX_DELTA_BIC:
                return None
            name = lead._added.effect
            say(f"round 2: nothing significant alone; {name} (ΔBIC {lead.delta_bic:.0f}, "
                f"gain {100 * lead.score:+.1f} %) fitted with each other candidate")
            pairs = run(lead, [f._added.effect for f in fits if f is not lead],
                        "round 2 (pairs)", {f._added.effect: f for f in fits})
            for f in pairs:
                f.score_against(ref, False)
            rounds.append(sorted(pairs, key=lambda f: (-f.significant, -f.score)))
            for f in rounds[-1][:3]:
                say(f"round 2: {name} + {f._added.effect} gain {100 * f.score:+.1f} %, "
                    f"ΔBIC {f.delta_bic:.0f}{' (significant)' if f.significant else ''}")
            sig = [f for f in pairs if f.significant]
            if not sig:
                return None
            partner = max(sig, key=lambda f: f.score)
            nonlocal pair_gain
            pair_gain = partner.score
            say(f"added {name} and {partner._added.effect} together: held-out gain "
                f"{100 * pair_gain:.1f} % against the refitted model")
            partner.score_against(lead, False)
            return [lead, partner]

        say(f"round 1: the paper's model refitted and {len(cands)} candidates fitted with "
            f"it ({min(jobs, len(cands) + 1) if executor is None else 'executor'} "
            "processes)" + (", and the rig's delay (the chain candidate)" if estimate
                            else ""))
        chain_slot = [CHAIN] if estimate else []
        first = run(None, [None, *chain_slot, *by_effect], "round 1")
        refit, fits = first[0], first[1:]
        chain_fit = fits.pop(0) if estimate else None
        present = refit
        remaining = list(by_effect)

        def within_floor(f: StepFit) -> bool:
            """``f``'s held-out residual is within the floor."""
            res = f.residuals(held)
            return pooled_rms(res) <= floor_level(held, res)[0]

        def runners_with_delay(present: StepFit, small: bool,
                               sig: list[StepFit]) -> StepFit | None:
            """The runners-up with the rig's delay: the rig's delay is significant,
            an effect (the leader) gains more but leaves structure.  The rig may hold
            another effect and a delay (a recorded cavity: the delay alone cannot follow
            the cavity, the cavity alone not the delay, and free air half follows each and
            leads).  The next ``CHAIN_RUNNERS`` significant effects are fitted again with
            the delay free, from ``present`` with the delay at its neutral start (the
            chain candidate's own delay is biased by the effect it stood in for).  One is
            returned (the largest gain) where the delay is significant on top of that
            effect alone and beyond ``MIN_T_RATIO`` σ of zero, and the two together are
            significant against the leader and cut its held-out r.m.s. by at least
            ``MIN_GAIN_OVER_LEADER``: the leader is not fitted with the delay,
            as a delay also follows part of an effect of the same shape (free air, a
            compliance), and is tried again on top of the leader in the next round."""
            ranked = sorted(sig, key=lambda f: -f.score)
            leader, runners = ranked[0], ranked[1:1 + CHAIN_RUNNERS]
            if not runners:
                return None
            start = StepFit(cfg, list(present.candidates), {
                **present.out, "base_values": {**present.out["base_values"],
                                               ACQUISITION_DELAY: ESTIMATED_DELAY_START_S}})
            label = f"round {len(rounds) + 1} (the runners-up with the rig's delay)"
            both = run(start, [f._added.effect for f in runners], label,
                       {f._added.effect: f for f in runners})
            taken: StepFit | None = None
            for b, alone in zip(both, runners):
                b.score_against(alone, within_floor(alone))
                on_top = b.significant
                b.score_against(leader, within_floor(leader))
                over_leader = b.significant and b.score >= MIN_GAIN_OVER_LEADER
                b.score_against(present, small)
                tau = b.out["base_values"][ACQUISITION_DELAY]
                sd = b.out["base_std"].get(ACQUISITION_DELAY, math.inf)
                say(f"{label}: {alone._added.effect} with the delay {1e3 * tau:.3f} ± "
                    f"{1e3 * sd:.3g} ms: gain {100 * b.score:+.1f} %; the delay "
                    f"{'' if on_top else 'not '}significant on top of it; "
                    f"{'' if over_leader else 'not '}enough over {leader._added.effect}")
                if (on_top and over_leader and b.significant and tau > MIN_T_RATIO * sd
                        and (taken is None or b.score > taken.score)):
                    taken = b
            if taken is not None:
                say(f"{label}: the rig's delay taken with {taken._added.effect}: every "
                    "later fit frees it")
            return taken

        while True:
            held_res = present.residuals(held)
            floor, _noise = floor_level(held, held_res)
            small = pooled_rms(held_res) <= floor
            for f in fits:
                f.score_against(present, small)
            sig = [f for f in fits if f.significant]
            if chain_fit is not None:
                chain_fit.score_against(present, small)
                say(f"round {len(rounds) + 1}: the rig's delay "
                    f"{1e3 * chain_fit.out['base_values'][ACQUISITION_DELAY]:.3f} ms gain "
                    f"{100 * chain_fit.score:+.1f} %, ΔBIC {chain_fit.delta_bic:.0f}"
                    f"{' (significant)' if chain_fit.significant else ''}")
                if chain_fit.significant and all(chain_fit.score >= f.score for f in sig):
                    # the rig explains more than any effect: taken (not an effect), and
                    # the round again on top of it, every fit with the delay free
                    say(f"round {len(rounds) + 1}: the rig's delay taken: "
                        "every later fit frees it")
                    chain_taken = chain_fit
                    if steps:  # the last step's model, with the delay
                        steps[-1] = chain_fit.replaces(steps[-1])
                    if within_floor(chain_taken):
                        # nothing left to explain, no round again: this round's fits,
                        # scored against the model with the delay, are the record (none
                        # can be significant)
                        for f in fits:
                            f.score_against(chain_taken, True)
                        rounds.append(sorted(fits, key=lambda f: -f.score))
                        say(f"round {len(rounds)}: with the rig's delay the held-out "
                            "r.m.s. is within the floor: nothing more to explain")
                        present = chain_taken  # (steps[-1], where there are steps)
                        if not steps:
                            refit = present
                        break
                    nxt = run(chain_fit, [None, *remaining], f"round {len(rounds) + 1} "
                              "(with the rig's delay)", {f._added.effect: f for f in fits})
                    present, fits, chain_fit = nxt[0], nxt[1:], None
                    if present.sse_held > chain_taken.sse_held:
                        present = chain_taken
                    if not steps:
                        refit = present
                    continue
                if (chain_fit.significant and sig
                        and not within_floor(max(sig, key=lambda f: f.score))):
                    with_delay = runners_with_delay(present, small, sig)
                    if with_delay is not None:
                        fits = [f for f in fits if f._added.effect
                                != with_delay._added.effect] + [with_delay]
                        sig, chain_fit = [with_delay], None
            rounds.append(sorted(fits, key=lambda f: (-f.significant, -f.score)))
            for f in rounds[-1][:3]:
                say(f"round {len(rounds)}: {f._added.effect} gain {100 * f.score:+.1f} %, "
                    f"ΔBIC {f.delta_bic:.0f}{' (significant)' if f.significant else ''}")
            if small:
                say(f"round {len(rounds)}: held-out r.m.s. {pooled_rms(held_res):.2f} N is "
                    f"within the floor {floor:.2f} N: nothing more to explain")
            if (not sig and not steps and not small and max_effects >= 2
                    and structure_ratio(held_res) > STRUCTURE_RATIO):
                pair = pair_search(present, fits)
                if pair is not None:
                    steps += pair
                break
            if not sig:
                break
            best = max(sig, key=lambda f: f.score)
            steps.append(best)
            remaining.remove(best._added.effect)
            say(f"added {best._added.effect} ({best._added.family}): held-out gain "
                f"{100 * best.score:.1f} %")
            if len(steps) >= max_effects or not remaining or within_floor(best):
                break
            # the next round: the present model refitted once more (the reference: a
            # candidate must beat the present model's own further convergence, not only
            # its last fit) and every remaining candidate on top of it
            # (each candidate also from its own fit of this round: joint_fit, the other
            # order); the chain candidate again while it has not been taken
            with_chain = [CHAIN] if chain_fit is not None else []
            nxt = run(best, [None, *with_chain, *remaining], f"round {len(rounds) + 1}",
                      {f._added.effect: f for f in fits})
            present, fits = nxt[0], nxt[1:]
            if with_chain:
                chain_fit = fits.pop(0)
            if present.sse_held > best.sse_held:
                present = best

        if estimate and steps and ACQUISITION_DELAY not in steps[-1].out["base_values"]:
            # the effects are in: the rig's delay on top of them, taken if significant
            (last,) = run(steps[-1], [CHAIN], "the rig's delay on the effects")
            last.score_against(steps[-1], within_floor(steps[-1]))
            say(f"the rig's delay {1e3 * last.out['base_values'][ACQUISITION_DELAY]:.3f} "
                f"ms on the effects: gain {100 * last.score:+.1f} %, ΔBIC "
                f"{last.delta_bic:.0f}{' (taken)' if last.significant else ''}")
            if last.significant:
                steps[-1] = last.replaces(steps[-1])

    ref_held = refit.residuals(held)
    floor, noise = floor_level(held, ref_held)
    structure_ref = structure_ratio(ref_held)
    steps, closest, explained, pair_gain = weigh_effects(refit, ref_held, steps, held, floor,
                                                         pair_gain)
    if steps:
        family, effect = steps[0]._added.family, steps[0]._added.effect
    else:
        family = ("other" if structure_ref > STRUCTURE_RATIO and pooled_rms(ref_held) > floor
                  else "none")
        effect = None
    diag = Diagnosis(family=family, effect=effect, significant=bool(steps),
                     rms_before=rms_before, rms_after={}, ranking=rounds[0] if rounds else [],
                     held_out=[r.name for r in held],
                     structure_before=structure_ratio([base_res[r.name] for r in held]),
                     structure_after=0.0, seconds=0.0, refit=refit, steps=steps,
                     rounds=rounds, closest=closest, explained=explained, floor_n=floor,
                     noise_n=noise, base_model=base, records=records, pair_gain=pair_gain)
    after_model, after_rig = diag.model_after(), diag.rig_after()
    after = {r.name: r.residual(after_model, rig=after_rig) for r in records}
    diag.rms_after = {r.name: rms(after[r.name]) for r in records}
    diag.structure_after = structure_ratio([after[r.name] for r in held])
    if discovery:
        found = _discover(diag, base, fit, held, weights, floor, n_quasi_static, nfev, say)
        diag.discovered = found
        if found is not None and found.significant:
            diag.rms_after = dict(found.rms_after)
            diag.structure_after = structure_ratio(
                [term - missing for term, missing, _ in found.series.values()])
            if not steps:
                family = diag.family = found.family_hint or "other"
                diag.effect = "discovered"
                diag.significant = True
    diag.seconds = time.perf_counter() - t_start
    say(f"diagnosis: {family}" + (f" ({', '.join(s._added.effect for s in steps)})"
                                  if steps else "") + f" in {diag.seconds:.1f} s")
    return diag
