"""Which missing effects explain the residual: tell the rig from the damper, re-identify
the damper with each candidate inside the model, score on held-out data, add effects by
forward selection, or say ``none`` / ``other``.

:func:`diagnose` is a pipeline of stages, each a function of its own:

0. **The rig's lines** (:func:`take_out_lines`, module
   :mod:`~damper_emulator.diagnose.interference`): narrow-band interference on the force
   channel is found in the identified model's residual, fitted in every file and taken out
   of the recorded force before anything is fitted or scored.
1. **The session** (:func:`~damper_emulator.diagnose.session.prepare`): the records, the
   identified model's residual, the fits' weights and the candidates.
2. **The series** (:func:`follow_series`, module
   :mod:`~damper_emulator.diagnose.series`): what moves from file to file (the rig's zero
   and gain, the damper's gas charge, friction and valves), taken per file beside every
   later fit and score; then, where the files carry no chain, the force's scale
   (:func:`~damper_emulator.diagnose.scale.weigh_scale`): a gain of every file alike,
   as the oil's compressibility freed.
3. **The library's rounds** (:class:`~damper_emulator.diagnose.rounds.LibraryRounds`),
   steps 1–6 below.
4. **The answer** (:func:`answer`), step 7.
5. **The term discovery** (:func:`discover_term`) on what the library left; where
   structure still remains, again with the model's parameters free beside the term
   (:func:`discover_with_model_free`).

The library's rounds and the answer (steps 1–7):

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
   fitted again on top of it (step 3); this repeats until none is significant, the
   held-out residual is within :data:`SEARCH_NOISE_FACTOR` × its noise level (the floor
   before the first effect), or :data:`MAX_EFFECTS` are in.  Below that first floor a
   candidate that makes one identification file worse by more than
   :data:`~damper_emulator.diagnose.outcome.MAX_FILE_BIC_RISE` of its own effective BIC is
   not significant: it trades files, standing in for the present effects' form error
   (:meth:`StepFit.refuse_trade`).
   **Backward elimination** once the search ends with two effects or more (not a pair):
   each effect added before the last is tried away, the others refitted without it; it
   goes where the effects with it gain less than :data:`MIN_SCORE` held out against them
   (:meth:`~damper_emulator.diagnose.rounds.LibraryRounds.prune`).
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
   remains: then ``other``, the first as the closest family, nothing added.  Where most of
   what they left lies where the fit files leave an effect's law undetermined
   (:mod:`~damper_emulator.diagnose.undetermined`), that share is asked of the samples
   outside those regions.

**The rig's delay** (no chain given: ``docs/diagnose.md``, "The measurement chain")
competes in every round as the chain candidate: taken when it gains at least as much as
every significant effect; taken with a runner-up where an effect gains more but leaves
structure and the runner-up with the delay gains significantly more than it; else tried
once more on top of the effects added.

**The floor** ("small in engineering terms") is the larger of :data:`FLOOR_FORCE_FRACTION`
of the held-out force r.m.s. and :data:`FLOOR_NOISE_FACTOR` × the held-out noise level.
0.5 % of the force is the accuracy of a good dyno's force channel (load cells and their
amplifiers are specified to 0.5–1 % of reading); a model within it has nothing left to
explain that the instrument could vouch for.  A residual within three times its
white-noise level is "within 3× the noise": at most √8 σ of structure.  Once an effect is
in, the search goes on while the residual exceeds :data:`SEARCH_NOISE_FACTOR` × its noise
level, whatever the force.

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

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from typing import cast

import numpy as np

from damper_emulator.blas import one_blas_thread
from damper_emulator.diagnose.base import Record
from damper_emulator.diagnose.discovery import Discovery, ModelFree, discover, refit_with_term
from damper_emulator.diagnose.joint import JOINT_NFEV, model_jacobians
from damper_emulator.diagnose.measurement import (
    chain_findings,
    drift_findings,
    line_findings,
    screen_delay,
    take_out_lines,
)
from damper_emulator.diagnose.numerics import check_substep
from damper_emulator.diagnose.outcome import (
    MAX_DELTA_BIC,
    MAX_EFFECTS,
    MIN_EXPLAINED,
    MIN_SCORE,
    SEARCH_NOISE_FACTOR,
    STRUCTURE_RATIO,
    Diagnosis,
    StepFit,
    explained_fraction,
    floor_level,
    pooled_rms,
    structure_ratio,
)
from damper_emulator.diagnose.pool import LocalPool
from damper_emulator.diagnose.rounds import CHAIN, LibraryRounds, RoundsOutcome
from damper_emulator.diagnose.scale import scale_findings, weigh_scale
from damper_emulator.diagnose.series import SeriesResult
from damper_emulator.diagnose.series_stage import follow_series
from damper_emulator.diagnose.session import Say, Session, check_inputs, prepare, records_of
from damper_emulator.diagnose.undetermined import (
    MIN_UNDETERMINED_SHARE,
    determined_masks,
    explained_where,
    power_share,
    undetermined_findings,
)
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.model.compressible import DamperModel
from damper_emulator.validation import rms

__all__ = ["answer", "check_series", "diagnose", "discover_term", "weigh_effects"]

Progress = Callable[[str], None] | None


def weigh_effects(refit: StepFit, ref_held: Sequence[np.ndarray], steps: list[StepFit],
                  held: Sequence[Record], floor: float, pair_gain: float | None,
                  min_explained: float = MIN_EXPLAINED,
                  structure: float = STRUCTURE_RATIO,
                  determined: Sequence[np.ndarray] | None = None
                  ) -> tuple[list[StepFit], StepFit | None, float, float | None]:
    """Step 7 on the effects ``steps`` added (``pair_gain``: found as a pair): whether
    they explain enough of the refitted model's held-out residual ``ref_held`` (on the
    records ``held``).  ``determined``: per held-out record, its counted samples where
    the fit files determine the effects' laws
    (:func:`~damper_emulator.diagnose.undetermined.determined_masks`).

    Returns ``(steps, closest, explained, pair_gain)``: ``steps`` unchanged, unless they
    remove less than ``min_explained`` of the structured power while the residual stays
    above ``floor`` and above ``structure`` × its noise level, and (given ``determined``)
    less than that where their laws are determined too or most of what they left lies
    there; then no step, and the closest is the first step (for a pair, the pair's fit,
    scored against ``refit``)."""
    if not steps:
        return steps, None, 0.0, pair_gain
    final_held = steps[-1].residuals(held)
    explained = explained_fraction(ref_held, final_held)
    if (explained >= min_explained or structure_ratio(final_held) <= structure
            or pooled_rms(final_held) <= floor):
        return steps, None, explained, pair_gain
    if (determined is not None
            and power_share(final_held, [~m for m in determined]) >= MIN_UNDETERMINED_SHARE
            and explained_where(ref_held, final_held, determined) >= min_explained):
        return steps, None, explained, pair_gain   # the rest: where the files cannot tell
    closest = steps[0]
    if pair_gain is not None:  # the pair's fit, scored as a pair
        closest = steps[-1]
        closest.score_against(refit, False)
    return [], closest, explained, None


def answer(session: Session, found: RoundsOutcome, drift: SeriesResult) -> Diagnosis:
    """Stage 4 (step 7): the family from the effects added, weighed against the refitted
    model's held-out residual, or from a damper parameter that moves over the series
    where no effect was added; the model after the diagnosis and its residuals."""
    held = session.held
    refit = found.refit
    ref_held = refit.residuals(held)
    floor, noise = floor_level(held, ref_held)
    structure_ref = structure_ratio(ref_held)
    # the effects added, as fitted together last
    accepted = found.steps[-1].candidates if found.steps else []
    values = found.steps[-1].out["values"] if found.steps else []
    steps, closest, explained, pair_gain = weigh_effects(
        refit, ref_held, found.steps, held, floor, found.pair_gain,
        determined=determined_masks(accepted, values, held))
    damper_drift = [d for d in drift.taken if d.kind.family is not None]
    effect: str | None
    if steps:
        family, effect = steps[0]._added.family, steps[0]._added.effect
    elif damper_drift:
        family, effect = str(damper_drift[0].kind.family), "drift"
    else:
        family = ("other" if structure_ref > STRUCTURE_RATIO and pooled_rms(ref_held) > floor
                  else "none")
        effect = None
    diag = Diagnosis(family=family, effect=effect,
                     significant=bool(steps) or bool(damper_drift),
                     rms_before=dict(session.rms_before), rms_after={},
                     ranking=found.rounds[0] if found.rounds else [],
                     held_out=[r.name for r in held],
                     structure_before=structure_ratio([session.base_res[r.name]
                                                       for r in held]),
                     structure_after=0.0, seconds=0.0, refit=refit, steps=steps,
                     rounds=found.rounds, closest=closest, explained=explained,
                     floor_n=floor, noise_n=noise, base_model=session.base,
                     records=session.records, pair_gain=pair_gain, series=drift,
                     dropped=found.steps if closest is not None else [],
                     pruned=found.pruned,
                     dropped_pair_gain=found.pair_gain if closest is not None else None)
    after_model, after_rig = diag.model_after(), diag.rig_after()
    after = {r.name: r.residual(after_model, rig=after_rig) for r in session.records}
    diag.rms_after = {r.name: rms(after[r.name]) for r in session.records}
    held_after = [after[r.name] for r in held]
    diag.structure_after = structure_ratio(held_after)
    diag.noise_after_n = floor_level(held, held_after)[1]
    diag.undetermined = undetermined_findings(accepted, values, held, held_after)
    return diag


def discovery_floor(first: float, noise_after: float | None) -> float:
    """The floor of the term discovery's gate [N]: ``first``, the refitted model's
    (:func:`~damper_emulator.diagnose.outcome.floor_level`), or, once an effect is in,
    :data:`SEARCH_NOISE_FACTOR` times ``noise_after``, the noise level of what the
    model after leaves on the held-out files, as the rounds go on.  The refitted model's
    level is not the noise's where an effect leaves a large smooth residual: a 4 ms valve
    lag's 370 N at 12 Hz raised it from 4 N to 10 N, and a second effect's 20 N was
    below its floor."""
    return first if noise_after is None else SEARCH_NOISE_FACTOR * noise_after


def discover_term(diag: Diagnosis, session: Session) -> Discovery:
    """Stage 5: the term discovery on what the library left (module
    :mod:`damper_emulator.diagnose.discovery`), from the model after the diagnosis and
    from the identified model (whose parameters no fit has bent towards the effect: a
    refit of the paper's model alone gave a 6 kg inertia's chirp 70 N of error on the
    quasi-static test), and from the latter with the local dictionary too (the zones for
    the damping polynomials), the one whose term gains more on the held-out files, as the
    candidates compete; then the term fitted jointly with the model after the
    diagnosis.  A significant term then holds the diagnosis's figures (and its family,
    where the library added nothing)."""
    say, fit, held, weights = session.say, session.fit, session.held, session.weights
    base, final = session.base, diag.final
    after_model, after_rig = diag.model_after(), diag.rig_after()
    floor = discovery_floor(diag.floor_n, diag.noise_after_n if diag.steps else None)
    say("discovery: what the library left, regressed on the dictionary of motion and "
        "model states")
    found = discover(after_model, after_rig, fit, held, weights, floor,
                     diag.structure_after, STRUCTURE_RATIO, MIN_SCORE, MAX_DELTA_BIC, say)
    if found.ran and final is not None:
        alt = discover(base, after_rig, fit, held, weights, 0.0, math.inf, STRUCTURE_RATIO,
                       MIN_SCORE, MAX_DELTA_BIC, say, dictionaries=(False, True))
        if alt.features and (not found.features
                             or alt.held_out_gain > found.held_out_gain):
            say("discovery: the term found on the identified model's residual is taken")
            found = alt
        if found.features:
            accepted = list(zip(final.candidates, final.out["values"]))
            found = refit_with_term(found, base.cfg, final.out["base_values"], accepted,
                                    fit, held, weights, final.residuals(fit),
                                    final.residuals(held), MIN_SCORE, MAX_DELTA_BIC,
                                    session.n_quasi_static, session.nfev, say)
        if diag.steps:
            found = discover_with_model_free(diag, session, found)
    if diag.dropped:
        found = beside_dropped(diag, session, found)
    diag.discovered = found
    if found.significant:
        diag.rms_after = dict(found.rms_after)
        left = held_with_term(found)
        diag.structure_after = structure_ratio(left)
        diag.noise_after_n = floor_level(held, left)[1]
        if not diag.steps and diag.effect != "drift":
            diag.family = found.family_hint or "other"
            diag.effect = "discovered"
            diag.significant = True
    return found


def discover_with_model_free(diag: Diagnosis, session: Session, found: Discovery
                             ) -> Discovery:
    """Stage 5 again where the effects and ``found`` (the term of the first discovery,
    refitted with them) still leave structure on the held-out files (their residual above
    ``SEARCH_NOISE_FACTOR`` times its noise): the discovery on the residual of the model
    after the library's effects with the model's parameters free to first order beside
    the term (:class:`~damper_emulator.diagnose.discovery.ModelFree`: their slopes at
    that model), the term then refitted with the model.  A fit that bent the paper's
    parameters towards a missing effect leaves a residual shaped by the bend: a cavity's
    fit beside a damping zone softened the gas four times, and the zone's profile was
    not among what the residual showed.  Taken where significant and, beside a
    significant ``found``, at least ``MIN_SCORE`` lower held out; the effects are then
    each tried away beside it (:func:`prune_beside`): one may have stood in for part of
    what the term now holds."""
    say, fit, held, weights = session.say, session.fit, session.held, session.weights
    final = cast(StepFit, diag.final)
    fit_before, held_before = final.residuals(fit), final.residuals(held)
    now = held_with_term(found) if found.significant else held_before
    noise = floor_level(held, now)[1]
    if pooled_rms(now) <= SEARCH_NOISE_FACTOR * noise:
        return found
    say(f"discovery: {pooled_rms(now):.1f} N left held out (over {SEARCH_NOISE_FACTOR:g}× "
        f"its noise {noise:.1f} N): again, with the model's parameters free beside the term")
    accepted = list(zip(final.candidates, final.out["values"]))
    on_fit, on_held = model_jacobians(session.base.cfg, final.out["base_values"],
                                      [(c.settled(v), v) for c, v in accepted], fit, held,
                                      weights, session.n_quasi_static)
    again = discover(diag.model_after(), diag.rig_after(), fit, held, weights, 0.0,
                     math.inf, STRUCTURE_RATIO, MIN_SCORE, MAX_DELTA_BIC, say,
                     dictionaries=(False, True), free=ModelFree(on_fit, on_held))
    if not again.features:
        return found
    again = best_refit(again, session, final, fit_before, held_before)
    if not again.significant or (found.significant and pooled_rms(held_with_term(again))
                                 > (1.0 - MIN_SCORE) * pooled_rms(now)):
        say("discovery: the term found with the model's parameters free is not taken")
        return found
    say("discovery: the term found with the model's parameters free is taken")
    steps, again = prune_beside(session, list(diag.steps), again, fit_before, held_before)
    if len(steps) < len(diag.steps):
        diag.steps, diag.pair_gain = steps, None
        diag.family, diag.effect = steps[0]._added.family, steps[0]._added.effect
        diag.explained = explained_fraction(cast(StepFit, diag.refit).residuals(held),
                                            held_with_term(again))
    return again


def best_refit(found: Discovery, session: Session, final: StepFit,
               fit_before: Sequence[np.ndarray], held_before: Sequence[np.ndarray]
               ) -> Discovery:
    """``found`` refitted with the model ``final`` (its residuals ``fit_before``,
    ``held_before``: the refits' reference) (:func:`refit_with_term`), and where
    it has several parts, each of them left out and the rest refitted: the significant
    one that leaves least held out (else the least of all).  The joint refit decides on
    the held-out files: a part that the discovery's linear step of the parameters needed
    may only extrapolate once the parameters themselves move."""
    say = session.say
    tries = [found] + [dataclasses.replace(
        found, features=[f for j, f in enumerate(found.features) if j != k],
        coefficients=np.delete(found.coefficients, k), std=np.delete(found.std, k))
        for k in range(len(found.features)) if len(found.features) > 1]
    accepted = list(zip(final.candidates, final.out["values"]))
    refits = []
    for t in tries:
        say(f"discovery: {t.expression} refitted with the model")
        refits.append(refit_with_term(t, session.base.cfg, final.out["base_values"],
                                      accepted, session.fit, session.held, session.weights,
                                      fit_before, held_before, MIN_SCORE, MAX_DELTA_BIC,
                                      session.n_quasi_static, session.nfev, say))
    return min(refits, key=lambda r: (not r.significant, pooled_rms(held_with_term(r))))


def beside_dropped(diag: Diagnosis, session: Session, alone: Discovery) -> Discovery:
    """Stage 5 where step 7 dropped the library's effects for explaining too little: a
    term discovered on what they left and fitted jointly with them.  The effects come
    back, with that term beside them (the library explained part, the term the rest),
    where the term is significant on top of them, together they explain at least
    :data:`MIN_EXPLAINED` of the refitted model's held-out structured power, and they
    leave at least :data:`MIN_SCORE` less held out than the term ``alone`` (on the
    refitted model) when that is significant; else ``alone`` is returned."""
    say, fit, held = session.say, session.fit, session.held
    last = diag.dropped[-1]
    names = " + ".join(last.effects)
    say(f"discovery: what {names} left (explaining {100 * diag.explained:.0f} %, too "
        "little alone)")
    found = discover(last.model(), last.rig, fit, held, session.weights, 0.0, math.inf,
                     STRUCTURE_RATIO, MIN_SCORE, MAX_DELTA_BIC, say)
    if not found.features:
        say(f"discovery: no term beside {names}: {found.reason}")
        return alone
    fit_before, held_before = last.residuals(fit), last.residuals(held)
    found = refit_with_term(found, session.base.cfg, last.out["base_values"],
                            list(zip(last.candidates, last.out["values"])), fit, held,
                            session.weights, fit_before, held_before, MIN_SCORE,
                            MAX_DELTA_BIC, session.n_quasi_static, session.nfev, say)
    if not found.significant:
        return alone
    ref_held = cast(StepFit, diag.refit).residuals(held)
    both_held = held_with_term(found)
    explained = explained_fraction(ref_held, both_held)
    gain = (1.0 - pooled_rms(both_held) / pooled_rms(held_with_term(alone))
            if alone.significant else math.inf)
    say(f"discovery: {names} and {found.expression} together explain "
        f"{100 * explained:.0f} % (at least {100 * MIN_EXPLAINED:.0f} %)"
        + (f", {100 * gain:+.1f} % held out against the term alone"
           if math.isfinite(gain) else ""))
    if explained < MIN_EXPLAINED or gain < MIN_SCORE:
        return alone
    steps, found = prune_beside(session, diag.dropped, found, fit_before, held_before)
    pair_gain = diag.dropped_pair_gain if len(steps) == len(diag.dropped) else None
    if pair_gain is not None:  # the partner scored against the lead again
        steps[-1].score_against(steps[0], False)
    explained = explained_fraction(ref_held, held_with_term(found))
    diag.steps, diag.closest, diag.explained = steps, None, explained
    diag.pair_gain, diag.dropped, diag.dropped_pair_gain = pair_gain, [], None
    diag.family, diag.effect = steps[0]._added.family, steps[0]._added.effect
    diag.significant = True
    return found


def prune_beside(session: Session, steps: list[StepFit], found: Discovery,
                 fit_before: Sequence[np.ndarray], held_before: Sequence[np.ndarray]
                 ) -> tuple[list[StepFit], Discovery]:
    """The effects beside a term, each tried away (the smallest held-out gain first,
    never the last): the term and the other effects fitted again without it, and it goes
    where it gains less than :data:`MIN_SCORE` held out on top of them.  A library effect
    may have taken part of what the term now holds (a valve lag that took an inertia's
    phase lead before the mass was there to take it).  ``found``: the term refitted with
    every effect of ``steps``; ``fit_before``, ``held_before``: the residuals of
    ``steps``' own fit without the term (the reference of the refits' own scores).
    Returns the effects kept and the term refitted with them."""
    say, fit, held = session.say, session.fit, session.held
    cands = [s._added for s in steps]
    kept = list(range(len(steps)))
    for k in sorted(kept, key=lambda j: steps[j].score):
        if len(kept) == 1:
            break
        rest = [j for j in kept if j != k]
        values = dict(zip(kept, found.effect_values))
        trial = refit_with_term(found, session.base.cfg, found.base_values,
                                [(cands[j], values[j]) for j in rest], fit, held,
                                session.weights, fit_before, held_before, MIN_SCORE,
                                MAX_DELTA_BIC, session.n_quasi_static, session.nfev)
        gain = 1.0 - (pooled_rms(held_with_term(found))
                      / pooled_rms(held_with_term(trial)))
        verdict = "kept" if gain >= MIN_SCORE or not trial.significant else "dropped"
        say(f"discovery: {cands[k].effect} beside the term and the other effects gains "
            f"{100 * gain:+.1f} % held out (at least {100 * MIN_SCORE:.0f} %): {verdict}")
        if verdict == "dropped":
            kept, found = rest, trial
    return [steps[j] for j in kept], found


def held_with_term(found: Discovery) -> list[np.ndarray]:
    """The held-out residuals with a discovered term (its plot series: the term and the
    force it is to explain)."""
    return [term - missing for term, missing, _ in found.series.values()]


@one_blas_thread
def diagnose(base: DamperModel, fit_data: Sequence[MeasuredData],
             held_out_data: Sequence[MeasuredData], effects: Sequence[str] | None = None,
             progress: Progress = None, jobs: int | None = None,
             executor: Executor | None = None, max_effects: int = MAX_EFFECTS,
             nfev: int = JOINT_NFEV, n_quasi_static: int = 1,
             discovery: bool = True, series: Sequence[str] | None = None) -> Diagnosis:
    """Diagnose the residual of ``base`` (the identified model) on ``fit_data``
    (quasi-static and chirp: fitted) and ``held_out_data`` (scored only), with the
    candidates ``effects`` (default: all); module docstring.  The first ``n_quasi_static``
    files of ``fit_data`` are quasi-static tests, the others chirps (the re-identification
    of a local effect needs to know which).

    ``discovery``: regress what the library leaves on the dictionary of
    :mod:`damper_emulator.diagnose.discovery` (stage 5).  ``series``: the files' names in
    the order they were recorded (default: the identification files, then the held-out
    files, as given), where the files' time columns are not one clock.

    The fits run on ``executor`` (any :class:`concurrent.futures.Executor`, e.g. a Dask
    client's ``get_executor()``) or, without one, in ``jobs`` forked processes (default
    one: in this process); those in this process on one BLAS thread, as each task's
    (:func:`~damper_emulator.blas.one_blas_thread`: OpenBLAS's threads spin
    before they sleep, against the Jacobian's threads and the pool's fits).

    Raises
    ------
    UserError
        One line: no held-out file, duplicate file names, a series order that does not
        name every file once, or a file the model cannot simulate (naming it).
    """
    say: Say = progress or (lambda msg: None)
    t_start = time.perf_counter()
    check_inputs(base, fit_data, held_out_data)
    recorded = records_of(fit_data, held_out_data)
    check_series(series, [r.name for r in recorded])
    rms_recorded = {r.name: rms(r.residual(base)) for r in recorded}
    first_look = screen_delay(base, recorded)
    lines, cleaned = take_out_lines(base, recorded, say, first_look)
    session = prepare(base, [cleaned[r.name] for r in recorded if not r.held_out],
                      [cleaned[r.name] for r in recorded if r.held_out], effects,
                      n_quasi_static, nfev, say, t_start)
    say("identified model: held-out r.m.s. "
        + ", ".join(f"{r.name} {session.rms_before[r.name]:.1f} N" for r in session.held))
    if session.estimate:
        say("no measurement chain given (--rig): the rig's delay of the force against the "
            "displacement competes with the effects (the chain candidate)")
    jobs_ = max(1, int(jobs or 1))
    with LocalPool(jobs_ if executor is None else 1) as local:
        rounds = LibraryRounds(session, local, executor, max_effects)
        chain_first = None
        if session.estimate:
            # the rig's delay first (the chain candidate of round 1): what moves over the
            # series is weighed on the paper's model refitted with it, not on an
            # identification that took a load-cell filter's lag into its valves
            (chain_first,) = rounds.run(None, [CHAIN], "the rig's delay, first")
        drift = follow_series(session, series, rounds, first_look, chain_first)
        present = chain_first if not drift.taken else None
        scale = weigh_scale(session, rounds, present)
        found = rounds.select(present if scale is None or not scale.taken else None)
    diag = answer(session, found, drift)
    diag.numerics_refined = found.refined
    diag.rms_before = rms_recorded
    diag.rms_before_rig = dict(session.rms_before)
    diag.lines = lines
    if discovery:
        discover_term(diag, session)
    after, rig_after = diag.model_after(), diag.rig_after()
    drift.refresh(session.records, after, rig_after)
    diag.numerics = check_substep(after, diag.records, rig_after, diag.noise_after_n)
    if not diag.numerics.converged:
        say(f"the model's integration: halving its sub-step moves its force by "
            f"{diag.numerics.change_n:.2f} N r.m.s. (noise level "
            f"{diag.numerics.noise_n:.2f} N): a shorter numerics.max_substep_s is worth it")
    diag.scale = scale
    diag.measurement = [*line_findings(lines), *drift_findings(drift.taken),
                        *scale_findings(scale),
                        *chain_findings(diag.acquisition_json(),
                                        recorded[0].data.acquisition)]
    diag.seconds = time.perf_counter() - t_start
    say(f"diagnosis: {diag.family}" + (f" ({', '.join(s._added.effect for s in diag.steps)})"
                                       if diag.steps else "") + f" in {diag.seconds:.1f} s")
    return diag


def check_series(order: Sequence[str] | None, names: Sequence[str]) -> None:
    """One line where a series order does not name every file exactly once."""
    from damper_emulator.errors import UserError

    if order is None:
        return
    if sorted(order) != sorted(names):
        missing = sorted(set(names) - set(order))
        extra = sorted(set(order) - set(names))
        what = (f"misses {missing[0]!r}" if missing else f"names {extra[0]!r}, which is no "
                "file of the diagnosis" if extra else "names a file twice")
        raise UserError(f"the series order {what}: it must name every data file once")
