"""Which missing effect explains the residual: fit every candidate, score it on held-out
data, pick one or say ``none`` / ``other``.

Procedure (:func:`diagnose`):

1. **Base.**  The identified model is simulated over every file (the same simulation as
   ``validate``: :func:`damper_emulator.validation.simulate_record`); the residuals
   ``F_sim − F_meas`` are the "before".
2. **Fit.**  Each candidate (:mod:`damper_emulator.diagnose.candidates`) is added to the
   identified model, whose own parameters stay fixed, and its parameters are fitted on the
   identification files (quasi-static + chirp) by bounded least squares
   (``scipy.optimize.least_squares``, trust-region reflective, forward differences) in
   coordinates normalised to the bounds; a candidate with several start vectors gets
   :data:`SCREEN_NFEV` evaluations from each and goes on from the best.  The cost is
   ``Σ_f MSE_f(θ) / MSE_f(base)``: every file counts by the fraction of its own residual
   power removed, so a quasi-static test of a few hundred newtons weighs as much as a
   chirp of kilonewtons.
3. **Score** on the held-out files (the validation sines), never seen by the fit:
   ``score = 1 − √(Σ SSE_after / Σ SSE_before)``, the pooled r.m.s. reduction.
4. **Penalise** the added parameters with the Bayesian information criterion on the
   identification files, ``BIC = Σ_f n_f,eff ln MSE_f + k ln N_eff``, with each file's
   sample count reduced to the effective number of independent samples of an AR(1)
   residual, ``n_eff = n (1 − ρ)/(1 + ρ)`` (ρ the lag-1 autocorrelation of the candidate's
   residual; a residual of a dyno record is never white, and the plain BIC would take
   40 000 correlated samples as 40 000 pieces of evidence).
5. **Select.**  A candidate is *significant* when it cuts the held-out r.m.s. by at least
   :data:`MIN_SCORE` **and** ``ΔBIC ≤`` :data:`MAX_DELTA_BIC`.  The most significant
   candidate by score is the diagnosis, unless it removes less than :data:`MIN_EXPLAINED`
   of the held-out residual's structured power (:func:`explained_fraction`) and structure
   remains: then the answer is ``other``, with that candidate as the closest family and
   nothing added.  With none significant the result is ``other`` if the held-out residual
   still has structure — its r.m.s. more than :data:`STRUCTURE_RATIO` times the noise level
   estimated from sample-to-sample differences (:func:`noise_level`) — and ``none``
   otherwise.

Thresholds: ``MIN_SCORE`` = 5 %: on data without an extra effect (noise only) the best
candidate's held-out reduction stayed below 0.5 % (measured in ``docs/diagnose.md``), so 5 %
is ten times that; ``MAX_DELTA_BIC`` = −10 is "very strong" evidence on the Kass & Raftery
(1995) scale; ``STRUCTURE_RATIO`` = 1.5: white noise gives 1.0 ± 0.02 on these record lengths
and a residual 1.5× its noise floor carries more than half its power in structure
(1 − 1/1.5²  = 56 %).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
from scipy.optimize import least_squares

from damper_emulator.diagnose.candidates import Candidate, candidates as make_candidates
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import EXTENSION_TYPES, ExtensionParams, ParameterError
from damper_emulator.validation import record_velocity, rms, simulate_measured

#: a candidate must cut the pooled held-out r.m.s. by at least this fraction
MIN_SCORE = 0.05
#: ... and lower the effective BIC on the identification files by at least this much
MAX_DELTA_BIC = -10.0
#: held-out residual r.m.s. / noise level above which structure remains
STRUCTURE_RATIO = 1.5
#: a significant candidate that removes less than this fraction of the held-out residual's
#: structured power while structure remains is reported as the closest family of ``other``
MIN_EXPLAINED = 0.5
#: lag-1 autocorrelation is clipped to this in the effective sample size
MAX_RHO = 0.999
#: evaluations of the least-squares cost per start (Jacobian evaluations not counted)
MAX_NFEV = 30
#: ... of which each start of a candidate with several gets this many before the best
#: start goes on alone
SCREEN_NFEV = 4
#: forward-difference step in normalised coordinates (0.1 % of each parameter's range)
DIFF_STEP = 1e-3
#: cost returned for parameters the model refuses
FAILED_COST = 1e6
#: the first this many seconds of every file are left out of every figure: the model
#: starts from quasi-steady equilibrium at the first sample, the damper on the rig was
#: already moving, and an effect with its own state (a series spring's deflection, a
#: cavity, a lagging valve) takes a few of its time constants to agree
START_SKIP_S = 0.05

Progress = Optional[Callable[[str], None]]


@dataclass
class Record:
    """One file ready to simulate: samples, the velocity used, the temperature (or None)."""

    data: MeasuredData
    velocity: np.ndarray
    held_out: bool

    @property
    def name(self) -> str:
        return self.data.name or self.data.path

    @property
    def start(self) -> int:
        """Index of the first sample that counts (:data:`START_SKIP_S` in)."""
        t = self.data.time
        return min(int(np.searchsorted(t, t[0] + START_SKIP_S)), max(t.size - 3, 0))

    def simulate(self, model: DamperModel) -> np.ndarray:
        """The force [N] of ``model`` over the whole file (one line naming the file when it
        cannot be simulated)."""
        return simulate_measured(model, self.data, self.velocity).force_n

    def residual(self, model: DamperModel) -> np.ndarray:
        """``F_sim − F_meas`` [N] of ``model`` on this file, from :attr:`start` on."""
        k = self.start
        return self.simulate(model)[k:] - self.data.force[k:]


def make_record(data: MeasuredData, held_out: bool) -> Record:
    """The record of ``data`` with the velocity ``validate`` uses."""
    return Record(data, record_velocity(data)[0], held_out)


def lag1(r: np.ndarray) -> float:
    """Lag-1 autocorrelation of ``r`` (mean removed), clipped to ``[0, MAX_RHO]``."""
    r = r - r.mean()
    den = float(np.dot(r, r))
    if r.size < 3 or den <= 0.0:
        return 0.0
    return min(max(float(np.dot(r[1:], r[:-1])) / den, 0.0), MAX_RHO)


def noise_level(r: np.ndarray) -> float:
    """Robust standard deviation of the white part of ``r`` [N]: the median absolute
    deviation of the first differences, ``1.4826 MAD(Δr) / √2`` (a smooth model error
    hardly changes from one sample to the next; white noise of σ gives differences of
    σ√2)."""
    if r.size < 3:
        return 0.0
    d = np.diff(r)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def structure_ratio(residuals: Sequence[np.ndarray]) -> float:
    """Pooled r.m.s. over the pooled noise level of ``residuals`` (1 for white noise)."""
    sse = sum(float(np.dot(r, r)) for r in residuals)
    n = sum(r.size for r in residuals)
    noise = math.sqrt(sum(noise_level(r) ** 2 * r.size for r in residuals) / max(n, 1))
    return math.sqrt(sse / max(n, 1)) / noise if noise > 0 else math.inf


def explained_fraction(before: Sequence[np.ndarray], after: Sequence[np.ndarray]) -> float:
    """Fraction of the structured power (mean square less the noise level's square, pooled)
    of residuals ``before`` that is gone ``after``; noise levels from ``after``."""
    n = sum(r.size for r in before)
    noise2 = sum(noise_level(r) ** 2 * r.size for r in after) / max(n, 1)
    p0 = sum(float(np.dot(r, r)) for r in before) / max(n, 1) - noise2
    p1 = sum(float(np.dot(r, r)) for r in after) / max(n, 1) - noise2
    if p0 <= 0.0:
        return 0.0
    return 1.0 - max(p1, 0.0) / p0


def effective_bic(residuals: Sequence[np.ndarray], k: int,
                  rhos: Sequence[float] | None = None) -> float:
    """BIC of residuals with ``k`` added parameters (module docstring); ``rhos`` the lag-1
    autocorrelations to use (default: each residual's own)."""
    bic = 0.0
    n_eff_total = 0.0
    for i, r in enumerate(residuals):
        rho = lag1(r) if rhos is None else rhos[i]
        n_eff = r.size * (1.0 - rho) / (1.0 + rho)
        bic += n_eff * math.log(max(float(np.mean(r * r)), 1e-300))
        n_eff_total += n_eff
    return bic + k * math.log(max(n_eff_total, 2.0))


@dataclass
class CandidateResult:
    """One fitted candidate."""

    candidate: Candidate
    values: dict[str, float]
    std: dict[str, float]
    extension: dict[str, float]
    rms_fit: dict[str, float]
    rms_held_out: dict[str, float]
    score: float
    delta_bic: float
    significant: bool
    evaluations: int
    seconds: float

    def to_json(self) -> dict[str, Any]:
        c = self.candidate
        return {"effect": c.effect, "family": c.family, "score": self.score,
                "significant": self.significant, "delta_bic": self.delta_bic,
                "parameters": self.extension,
                "fitted": {p.name: {"value": self.values.get(p.name), "std": self.std.get(
                    p.name), "unit": p.unit, "bounds": [p.lo, p.hi]}
                    for p in c.parameters},
                "rms_fit": self.rms_fit, "rms_held_out": self.rms_held_out,
                "evaluations": self.evaluations, "seconds": round(self.seconds, 2),
                **({"note": c.note} if c.note else {})}


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`; :meth:`to_json` is the CONTRACT's ``diagnose`` JSON."""

    family: str
    effect: str | None
    significant: bool
    rms_before: dict[str, float]
    rms_after: dict[str, float]
    ranking: list[CandidateResult]
    held_out: list[str]
    structure_before: float
    structure_after: float
    seconds: float
    chosen: CandidateResult | None = None
    #: with ``other``: the significant candidate that explained too little to be the answer
    closest: CandidateResult | None = None
    #: fraction of the held-out residual's structured power the best significant candidate
    #: removed (:func:`explained_fraction`; 0 when none was significant)
    explained: float = 0.0
    base_model: DamperModel | None = None
    records: list[Record] = field(default_factory=list)

    def model_after(self) -> DamperModel:
        """The identified model with the chosen effect (the base model when none)."""
        if self.chosen is None:
            return self.base_model
        return with_candidate(self.base_model, self.chosen.candidate, self.chosen.values)

    def to_json(self) -> dict[str, Any]:
        chosen = self.chosen
        doc: dict[str, Any] = {
            "family": self.family, "effect": self.effect, "significant": self.significant,
            "rms_before": self.rms_before, "rms_after": self.rms_after,
            "candidates": [c.to_json() for c in self.ranking],
            "held_out": self.held_out,
            "fit_files": [r.name for r in self.records if not r.held_out],
            "parameters": chosen.extension if chosen else None,
            "uncertainties": ({p: chosen.std.get(p) for p in chosen.values}
                              if chosen else None),
            "score": chosen.score if chosen else None,
            "explained_fraction": self.explained,
            "closest": ({"effect": self.closest.candidate.effect,
                         "family": self.closest.candidate.family,
                         "score": self.closest.score,
                         "parameters": self.closest.extension}
                        if self.closest else None),
            "structure_ratio_before": self.structure_before,
            "structure_ratio_after": self.structure_after,
            "thresholds": {"min_score": MIN_SCORE, "max_delta_bic": MAX_DELTA_BIC,
                           "structure_ratio": STRUCTURE_RATIO,
                           "min_explained": MIN_EXPLAINED},
            "seconds": round(self.seconds, 2)}
        return doc


def with_candidate(base: DamperModel, cand: Candidate, values: Mapping[str, float]
                   ) -> DamperModel:
    """``base`` with candidate ``cand`` at parameter ``values``."""
    group = EXTENSION_TYPES[cand.effect](**cand.fields(values))
    return base.with_extensions(ExtensionParams(**{cand.effect: group}))


def _fit(cand: Candidate, base: DamperModel, fit: Sequence[Record],
         base_mse: Sequence[float]) -> tuple[dict[str, float], dict[str, float], int,
                                             list[np.ndarray]]:
    """Least-squares fit of ``cand`` on ``fit``: values, standard deviations, evaluations
    and the fit residuals."""
    params = cand.parameters
    lo = np.array([p.bounds[0] for p in params])
    hi = np.array([p.bounds[1] for p in params])
    width = hi - lo
    weights = [1.0 / math.sqrt((r.data.force.size - r.start) * m)
               for r, m in zip(fit, base_mse)]
    n_total = sum(r.data.force.size - r.start for r in fit)
    evals = [0]

    def values_of(s: np.ndarray) -> dict[str, float]:
        return {p.name: p.from_internal(lo[i] + width[i] * s[i]) for i, p in enumerate(params)}

    def fun(s: np.ndarray) -> np.ndarray:
        evals[0] += 1
        try:
            model = with_candidate(base, cand, values_of(s))
        except (ParameterError, ValueError):
            return np.full(n_total, FAILED_COST)
        return np.concatenate([rec.residual(model) * w for rec, w in zip(fit, weights)])

    def solve(s0: np.ndarray, nfev: int):
        return least_squares(fun, s0, bounds=(0.0, 1.0), method="trf", diff_step=DIFF_STEP,
                             x_scale=1.0, max_nfev=nfev)

    starts = [np.clip((u0 - lo) / width, 0.0, 1.0) for u0 in cand.starts()]
    if len(starts) > 1:  # a few iterations from each start, then on from the best
        screened = min((solve(s0, SCREEN_NFEV) for s0 in starts), key=lambda r: r.cost)
        starts = [screened.x]
    best = solve(starts[0], MAX_NFEV)
    values = values_of(best.x)
    # covariance of the normalised coordinates, inflated for the residual's correlation
    model = with_candidate(base, cand, values)
    resid = [rec.residual(model) for rec in fit]
    std: dict[str, float] = {}
    jac = best.jac
    dof = max(best.fun.size - len(params), 1)
    s2 = 2.0 * best.cost / dof
    rho = max(lag1(r) for r in resid)
    try:
        cov = np.linalg.inv(jac.T @ jac) * s2 * (1.0 + rho) / (1.0 - rho)
        for i, p in enumerate(params):
            su = math.sqrt(max(cov[i, i], 0.0)) * width[i]
            std[p.name] = values[p.name] * math.log(10.0) * su if p.log else su
    except np.linalg.LinAlgError:
        std = {p.name: math.inf for p in params}
    return values, std, evals[0], resid


#: the work of one :func:`diagnose` call, for :func:`_evaluate` (in this process or in a
#: forked worker): base model, fit records, held-out records, candidates, base MSE of the
#: fit files, base SSE of the held-out files, base residuals of the fit files
_JOB: tuple | None = None


def _evaluate(i: int) -> dict[str, Any]:
    """Fit, score and penalise candidate ``i`` of :data:`_JOB` (plain values only, so that
    a worker process can return them)."""
    base, fit, held, cands, base_mse, sse_held_0, base_fit_res = _JOB
    cand = cands[i]
    t0 = time.perf_counter()
    values, std, nev, fit_res = _fit(cand, base, fit, base_mse)
    model = with_candidate(base, cand, values)
    held_res = [r.residual(model) for r in held]
    sse_held = sum(float(np.dot(h, h)) for h in held_res)
    score = 1.0 - math.sqrt(sse_held / sse_held_0) if sse_held_0 > 0 else 0.0
    rhos = [lag1(r) for r in fit_res]
    delta = (effective_bic(fit_res, len(cand.parameters), rhos)
             - effective_bic(base_fit_res, 0, rhos))
    return {"values": {k: float(v) for k, v in values.items()},
            "std": {k: float(v) for k, v in std.items()},
            "extension": {k: float(v) for k, v in cand.fields(values).items()},
            "rms_fit": {r.name: rms(x) for r, x in zip(fit, fit_res)},
            "rms_held_out": {r.name: rms(x) for r, x in zip(held, held_res)},
            "score": float(score), "delta_bic": float(delta),
            "significant": bool(score >= MIN_SCORE and delta <= MAX_DELTA_BIC),
            "evaluations": nev, "seconds": time.perf_counter() - t0}


def diagnose(base: DamperModel, fit_data: Sequence[MeasuredData],
             held_out_data: Sequence[MeasuredData], effects: Sequence[str] | None = None,
             progress: Progress = None, jobs: int | None = None) -> Diagnosis:
    """Fit every candidate effect on ``fit_data`` on top of ``base`` (the identified
    model), score it on ``held_out_data`` and choose (module docstring).  ``jobs`` > 1 fits
    the candidates in that many forked processes (default: one, in this process).

    Raises
    ------
    ValueError
        One line: no held-out file, duplicate file names, or a file the model cannot
        simulate (naming it).
    """
    say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    if not fit_data or not held_out_data:
        raise ValueError("diagnose needs identification files (quasi-static, chirp) and at "
                         "least one held-out validation file")
    names = [d.name or d.path for d in (*fit_data, *held_out_data)]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"two data files share the name {dup[0]!r}; names must differ")
    records = ([make_record(d, False) for d in fit_data]
               + [make_record(d, True) for d in held_out_data])
    fit = [r for r in records if not r.held_out]
    held = [r for r in records if r.held_out]
    base_res = {r.name: r.residual(base) for r in records}
    base_mse = [max(float(np.mean(base_res[r.name] ** 2)), 1e-12) for r in fit]
    rms_before = {r.name: rms(base_res[r.name]) for r in records}
    sse_held_0 = sum(float(np.dot(base_res[r.name], base_res[r.name])) for r in held)
    say("base model: held-out r.m.s. "
        + ", ".join(f"{r.name} {rms_before[r.name]:.1f} N" for r in held))
    cands = make_candidates(base.cfg, [r.data for r in fit], effects)
    global _JOB
    _JOB = (base, fit, held, cands, base_mse, sse_held_0,
            [base_res[r.name] for r in fit])
    results: list[CandidateResult | None] = [None] * len(cands)
    jobs = max(1, min(int(jobs or 1), len(cands)))
    say(f"fitting {len(cands)} candidates" + (f" in {jobs} processes" if jobs > 1 else ""))

    def done(i: int, out: dict[str, Any]) -> None:
        cand = cands[i]
        results[i] = CandidateResult(candidate=cand, **out)
        n_done = sum(r is not None for r in results)
        say(f"[{n_done}/{len(cands)}] {cand.effect} ({cand.family}, "
            f"{len(cand.parameters)} parameter{'s' if len(cand.parameters) > 1 else ''}): "
            f"held-out r.m.s. {-100 * out['score']:+.1f} %, ΔBIC {out['delta_bic']:.0f}"
            f"{'  (significant)' if out['significant'] else ''}, {out['seconds']:.1f} s")

    try:
        if jobs == 1:
            for i in range(len(cands)):
                done(i, _evaluate(i))
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor, as_completed

            # fork: the workers inherit the job and the compiled kernels
            with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("fork")
                                     ) as pool:
                futures = {pool.submit(_evaluate, i): i for i in range(len(cands))}
                for fut in as_completed(futures):
                    done(futures[fut], fut.result())
    finally:
        _JOB = None
    ranking = sorted(results, key=lambda c: (-c.significant, -c.score))
    chosen = ranking[0] if ranking and ranking[0].significant else None
    structure_before = structure_ratio([base_res[r.name] for r in held])
    closest = None
    explained = 0.0
    if chosen is not None:
        model = with_candidate(base, chosen.candidate, chosen.values)
        after = {r.name: r.residual(model) for r in records}
        explained = explained_fraction([base_res[r.name] for r in held],
                                       [after[r.name] for r in held])
        if (explained < MIN_EXPLAINED
                and structure_ratio([after[r.name] for r in held]) > STRUCTURE_RATIO):
            # a real but partial improvement: most of the structure is something else
            closest, chosen = chosen, None
    if chosen is not None:
        family, effect = chosen.candidate.family, chosen.candidate.effect
    else:
        after = base_res
        family = "other" if structure_before > STRUCTURE_RATIO else "none"
        effect = None
    structure_after = structure_ratio([after[r.name] for r in held])
    return Diagnosis(family=family, effect=effect, significant=chosen is not None,
                     rms_before=rms_before,
                     rms_after={r.name: rms(after[r.name]) for r in records},
                     ranking=ranking, held_out=[r.name for r in held],
                     structure_before=structure_before, structure_after=structure_after,
                     seconds=time.perf_counter() - t_start, chosen=chosen, base_model=base,
                     closest=closest, explained=explained,
                     records=records)
