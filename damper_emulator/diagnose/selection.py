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
from typing import Any, TypeVar, cast

import numpy as np

from damper_emulator.acquisition.chain import ESTIMATED_DELAY_START_S
from damper_emulator.diagnose.base import (
    ACQUISITION_DELAY,
    Record,
    base_parameters,
    chain_unknown,
    make_record,
)
from damper_emulator.diagnose.candidates import candidates as make_candidates
from damper_emulator.diagnose.discovery import Discovery, discover, refit_with_term
from damper_emulator.diagnose.joint import JOINT_NFEV
from damper_emulator.diagnose.outcome import (
    CHAIN_RUNNERS,
    MAX_DELTA_BIC,
    MAX_EFFECTS,
    MIN_EXPLAINED,
    MIN_GAIN_OVER_LEADER,
    MIN_NOISE_FRACTION,
    MIN_SCORE,
    MIN_T_RATIO,
    STRUCTURE_RATIO,
    Diagnosis,
    StepFit,
    explained_fraction,
    floor_level,
    noise_level,
    pooled_rms,
    structure_ratio,
)
from damper_emulator.diagnose.tasks import FitTask, run_fit_task
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel
from damper_emulator.validation import rms

__all__ = ["diagnose", "weigh_effects"]

Progress = Callable[[str], None] | None

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
