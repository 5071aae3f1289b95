"""The library's rounds: forward selection of the candidate effects, each fitted jointly
with the paper's parameters, scored on the held-out files (module
:mod:`damper_emulator.diagnose.selection`, steps 2–6), with the rig's delay as a
competitor where the chain is estimated.

:class:`LibraryRounds` holds a diagnosis's session and executor; :meth:`LibraryRounds.run`
is one round (its fits as tasks), :meth:`LibraryRounds.select` the whole selection, which
returns :class:`RoundsOutcome`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from damper_emulator.acquisition.chain import ESTIMATED_DELAY_START_S
from damper_emulator.diagnose.base import ACQUISITION_DELAY
from damper_emulator.diagnose.numerics import SubstepCheck, check_substep
from damper_emulator.diagnose.outcome import (
    CHAIN_RUNNERS,
    LATER_ROUND_CANDIDATES,
    MAX_DELTA_BIC,
    MIN_GAIN_OVER_LEADER,
    MIN_SCORE,
    MIN_T_RATIO,
    SEARCH_NOISE_FACTOR,
    STRUCTURE_RATIO,
    Pruned,
    StepFit,
    floor_level,
    pooled_rms,
    structure_ratio,
)
from damper_emulator.diagnose.pool import LocalPool, unordered
from damper_emulator.diagnose.session import Session
from damper_emulator.diagnose.tasks import FitTask, run_fit_task
from damper_emulator.diagnose.undetermined import determined_masks

__all__ = ["CHAIN", "LibraryRounds", "RoundsOutcome"]

#: the chain candidate's place in a round's list of effects
CHAIN = "(the rig's delay)"


@dataclass
class _Round:
    """The selection's state between rounds: the reference of the first round (the
    refitted paper's model, or with the rig's delay), the present model, this round's
    fits and the significant ones, the rig's delay while it competes, and the
    candidates not yet added."""

    refit: StepFit
    present: StepFit
    fits: list[StepFit]
    chain_fit: StepFit | None
    remaining: list[str]
    sig: list[StepFit] = field(default_factory=list)


@dataclass
class RoundsOutcome:
    """What the library's rounds found: the refitted paper's model (the first round's
    reference), the effects added (each fitted with all before it), every round's fits,
    and the pair's gain where two effects were found together."""

    refit: StepFit
    steps: list[StepFit] = field(default_factory=list)
    rounds: list[list[StepFit]] = field(default_factory=list)
    pair_gain: float | None = None
    pruned: list[Pruned] = field(default_factory=list)
    #: the check that halved the model's sub-step from there on (:meth:`LibraryRounds.
    #: refine`), or ``None``
    refined: SubstepCheck | None = None


class LibraryRounds:
    """The rounds of one diagnosis on ``session``'s records, the fits on ``executor`` or
    in ``jobs`` local processes; at most ``max_effects`` effects."""

    def __init__(self, session: Session, local: LocalPool, executor: Executor | None,
                 max_effects: int):
        self.s = session
        self.local = local
        self.executor = executor
        self.max_effects = max_effects
        self.rounds: list[list[StepFit]] = []
        self.steps: list[StepFit] = []
        self.pair_gain: float | None = None
        self.pruned: list[Pruned] = []
        self.refined: SubstepCheck | None = None

    # -- one round ---------------------------------------------------------------------
    def task(self, present: StepFit | None, effect: str | None,
             before: StepFit | None = None, start: Mapping[str, float] | None = None
             ) -> FitTask:
        """The task that fits ``effect`` (``None``: the present model alone; ``CHAIN``:
        the rig's delay) on top of ``present`` (``None``: the identified model), from
        ``start`` where given (pseudo-parameters too: a delay there is freed)."""
        s = self.s
        acc: tuple[tuple[str, Mapping[str, float]], ...]
        if present is None:
            bv, acc = s.base_values, ()
        else:
            bv = present.out["base_values"]
            acc = tuple(zip(present.effects, present.out["values"]))
        # an effect that replaces a paper's parameter leaves it at the identified value
        bv = {**s.base_values, **bv, **(start or {})}
        alt = (None if before is None else
               (before.out["base_values"], dict(zip(before.effects, before.out["values"]))))
        chain = effect == CHAIN
        return FitTask(s.cfg, tuple(r.data for r in s.fit), tuple(r.data for r in s.held),
                       tuple(s.weights), bv, acc, None if chain else effect, s.nfev,
                       s.n_quasi_static, alt, chain, tuple(s.per_file.items()))

    def step_fit(self, present: StepFit | None, out: dict[str, Any]) -> StepFit:
        order = [] if present is None else list(present.candidates)
        if out["effect"] is not None:
            order.append(self.s.candidates[out["effect"]])
        return StepFit(self.s.cfg, order, out)

    def run(self, present: StepFit | None, effects: Sequence[str | None], label: str,
            before: Mapping[str, StepFit] | None = None) -> list[StepFit]:
        """One round: each of ``effects`` fitted on top of ``present`` (each also from its
        fit ``before``, the other order), in ``effects``' order."""
        by_effect = self.s.candidates
        # the longest fits first (a round ends with its last fit: better several short
        # ones than one long one alone on a worker)
        order = sorted(range(len(effects)), key=lambda i: -(
            by_effect[e].relative_cost if (e := effects[i]) in by_effect else 0))
        tasks = [self.task(present, e, (before or {}).get(e) if e in by_effect else None)
                 for e in (effects[i] for i in order)]
        done = self.execute(present, tasks, label)
        out: list[StepFit | None] = [None] * len(tasks)
        for i, fit in enumerate(done):
            out[order[i]] = fit
        return cast("list[StepFit]", out)  # every task has filled its slot

    def execute(self, present: StepFit | None, tasks: Sequence[FitTask], label: str
                ) -> list[StepFit]:
        """The fits of ``tasks`` (on top of ``present``), in the tasks' order."""
        out: list[StepFit | None] = [None] * len(tasks)
        it = (unordered(self.executor, run_fit_task, tasks) if self.executor is not None
              else self.local.map_unordered(run_fit_task, tasks))
        for n_done, (i, res) in enumerate(it, 1):
            out[i] = self.step_fit(present, res)
            e = res["effect"] or ("the rig's delay" if res["chain"]
                                  else "present model alone")
            self.s.say(f"{label} [{n_done}/{len(tasks)}] {e}: held-out r.m.s. "
                       + ", ".join(f"{v['rms']:.1f}" for v in res["held"].values())
                       + f" N ({res['evaluations']} simulations, {res['seconds']:.1f} s; "
                       f"{self.s.elapsed():.0f} s into the diagnosis)")
        return cast("list[StepFit]", out)  # every task has filled its slot

    def within_floor(self, f: StepFit) -> bool:
        """``f``'s held-out residual is within the floor."""
        res = f.residuals(self.s.held)
        return pooled_rms(res) <= floor_level(self.s.held, res)[0]

    def settled(self, f: StepFit) -> bool:
        """Whether the search ends on ``f``, a model with an effect: its held-out residual
        within :data:`SEARCH_NOISE_FACTOR` times its noise level where the fit files
        determine the laws of its effects (:func:`~damper_emulator.diagnose.
        undetermined.determined_masks`; everywhere, where they determine them all).

        What lies where they do not is no further effect's to tell either: each is
        fitted on the same files (a hydraulic stop whose orifice the paper's programme
        cannot determine left 406 N on a held-out sine, and a second round of ten fits
        on top of the stops gained at most 0.3 %)."""
        held = self.s.held
        res = f.residuals(held)
        masks = determined_masks(f.candidates, f.out["values"], held)
        where = res if masks is None else [r[m] for r, m in zip(res, masks, strict=True)]
        return pooled_rms(where) <= SEARCH_NOISE_FACTOR * floor_level(held, res)[1]

    # -- the pair and the runners-up ---------------------------------------------------
    def pair_search(self, ref: StepFit, fits: list[StepFit]) -> list[StepFit] | None:
        """Step 6's pair: the fit with the most evidence on the identification files
        (the lowest ΔBIC, at most ``MAX_DELTA_BIC``) fitted with each other candidate,
        each pair scored against ``ref``; ``[lead, partner]`` (the partner scored
        against the lead, as a second step is) or ``None``."""
        say = self.s.say
        if len(fits) < 2:
            return None
        lead = min(fits, key=lambda f: f.delta_bic)
        if lead.delta_bic > MAX_DELTA_BIC:
            return None
        name = lead._added.effect
        say(f"round 2: nothing significant alone; {name} (ΔBIC {lead.delta_bic:.0f}, "
            f"gain {100 * lead.score:+.1f} %) fitted with each other candidate")
        pairs = self.run(lead, [f._added.effect for f in fits if f is not lead],
                         "round 2 (pairs)", {f._added.effect: f for f in fits})
        for f in pairs:
            f.score_against(ref, False)
        self.rounds.append(sorted(pairs, key=lambda f: (-f.significant, -f.score)))
        for f in self.rounds[-1][:3]:
            say(f"round 2: {name} + {f._added.effect} gain {100 * f.score:+.1f} %, "
                f"ΔBIC {f.delta_bic:.0f}{' (significant)' if f.significant else ''}")
        sig = [f for f in pairs if f.significant]
        if not sig:
            return None
        partner = max(sig, key=lambda f: f.score)
        self.pair_gain = partner.score
        say(f"added {name} and {partner._added.effect} together: held-out gain "
            f"{100 * self.pair_gain:.1f} % against the refitted model")
        partner.score_against(lead, False)
        return [lead, partner]

    def runners_with_delay(self, present: StepFit, small: bool,
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
        start = StepFit(self.s.cfg, list(present.candidates), {
            **present.out, "base_values": {**present.out["base_values"],
                                           ACQUISITION_DELAY: ESTIMATED_DELAY_START_S}})
        label = f"round {len(self.rounds) + 1} (the runners-up with the rig's delay)"
        both = self.run(start, [f._added.effect for f in runners], label,
                        {f._added.effect: f for f in runners})
        taken: StepFit | None = None
        for b, alone in zip(both, runners):
            b.score_against(alone, self.within_floor(alone))
            on_top = b.significant
            b.score_against(leader, self.within_floor(leader))
            over_leader = b.significant and b.score >= MIN_GAIN_OVER_LEADER
            b.score_against(present, small)
            tau = b.out["base_values"][ACQUISITION_DELAY]
            sd = b.out["base_std"].get(ACQUISITION_DELAY, math.inf)
            self.s.say(f"{label}: {alone._added.effect} with the delay {1e3 * tau:.3f} ± "
                       f"{1e3 * sd:.3g} ms: gain {100 * b.score:+.1f} %; the delay "
                       f"{'' if on_top else 'not '}significant on top of it; "
                       f"{'' if over_leader else 'not '}enough over {leader._added.effect}")
            if (on_top and over_leader and b.significant and tau > MIN_T_RATIO * sd
                    and (taken is None or b.score > taken.score)):
                taken = b
        if taken is not None:
            self.s.say(f"{label}: the rig's delay taken with {taken._added.effect}: every "
                       "later fit frees it")
        return taken

    # -- the selection -----------------------------------------------------------------
    def select(self, chain_first: StepFit | None = None) -> RoundsOutcome:
        """Forward selection (module :mod:`~damper_emulator.diagnose.selection`, steps
        2–6), the rig's delay competing where it is estimated (``chain_first``: its fit,
        made before the round, on the same per-file terms): each round scored, the
        rig's turn, the round recorded, then an effect added and the next round run,
        until nothing is significant or the search is settled."""
        st = self.first_round(chain_first)
        while True:
            held_res, floor, small = self.score_round(st)
            if st.chain_fit is not None:
                turn = self.chain_turn(st, small)
                if turn == "settled":
                    break
                if turn == "again":
                    continue
            self.record_round(st, held_res, floor, small)
            if (not st.sig and not self.steps and not small and self.max_effects >= 2
                    and structure_ratio(held_res) > STRUCTURE_RATIO):
                pair = self.pair_search(st.present, st.fits)
                if pair is not None:
                    self.steps += pair
                break
            if not st.sig or not self.next_round(st):
                break
        if self.steps:
            self.steps[-1] = self.refine(self.steps[-1], "the effects")
        self.prune(st.refit)
        self.delay_on_effects()
        return RoundsOutcome(st.refit, self.steps, self.rounds, self.pair_gain, self.pruned,
                             self.refined)

    def first_round(self, chain_first: StepFit | None) -> _Round:
        """Round 1: the paper's model refitted and every candidate fitted with it (and the
        rig's delay, where estimated and not fitted before)."""
        s = self.s
        by_effect = s.candidates
        workers = (min(self.local.jobs, len(by_effect) + 1) if self.executor is None
                   else "executor")
        s.say(f"round 1: the paper's model refitted and {len(by_effect)} candidates fitted "
              f"with it ({workers} processes)"
              + (", and the rig's delay (the chain candidate)" if s.estimate else ""))
        chain_slot = [CHAIN] if s.estimate and chain_first is None else []
        first = self.run(None, [None, *chain_slot, *by_effect], "round 1")
        refit, fits = first[0], first[1:]
        chain_fit = (chain_first if chain_first is not None
                     else fits.pop(0) if s.estimate else None)
        return _Round(refit, refit, fits, chain_fit, list(by_effect))

    def score_round(self, st: _Round) -> tuple[list[np.ndarray], float, bool]:
        """Every fit of the round scored against the present model: the held-out
        residual, the floor (once an effect is in, ``SEARCH_NOISE_FACTOR`` × its noise)
        and whether the residual is within it; ``st.sig`` the significant fits (below
        the first floor, none that trades files: :meth:`StepFit.refuse_trade`)."""
        held_res = st.present.residuals(self.s.held)
        floor, noise = floor_level(self.s.held, held_res)
        below = bool(self.steps) and pooled_rms(held_res) <= floor
        if self.steps:  # an effect is in: the search goes on while structure remains
            floor = SEARCH_NOISE_FACTOR * noise
        small = pooled_rms(held_res) <= floor
        for f in st.fits:
            f.score_against(st.present, small)
            if below and (trade := f.refuse_trade(st.present)) is not None:
                self.s.say(f"round {len(self.rounds) + 1}: {f._added.effect} gains "
                           f"{100 * f.score:+.1f} % below the floor but makes "
                           f"{trade[0]} worse (ΔBIC {trade[1]:+.0f}): it trades "
                           "files, not significant")
        st.sig = [f for f in st.fits if f.significant]
        return held_res, floor, small

    def chain_turn(self, st: _Round, small: bool) -> str:
        """The rig's delay weighed against the round's effects: taken where it explains
        more than any (``settled`` where the model with it is within the floor, else
        ``again``: the round run again on top of it, with the candidates a next round
        would take, :meth:`next_candidates`), or fitted with the runners-up where
        an effect gains more but leaves structure; ``on`` otherwise."""
        say, chain_fit = self.s.say, st.chain_fit
        assert chain_fit is not None  # (the caller's test)
        chain_fit.score_against(st.present, small)
        say(f"round {len(self.rounds) + 1}: the rig's delay "
            f"{1e3 * chain_fit.out['base_values'][ACQUISITION_DELAY]:.3f} ms gain "
            f"{100 * chain_fit.score:+.1f} %, ΔBIC {chain_fit.delta_bic:.0f}"
            f"{' (significant)' if chain_fit.significant else ''}")
        if chain_fit.significant and all(chain_fit.score >= f.score for f in st.sig):
            # the rig explains more than any effect: taken (not an effect), and the round
            # again on top of it, every fit with the delay free
            say(f"round {len(self.rounds) + 1}: the rig's delay taken: "
                "every later fit frees it")
            if self.steps:  # the last step's model, with the delay
                self.steps[-1] = chain_fit.replaces(self.steps[-1])
            if self.within_floor(chain_fit):
                # nothing left to explain, no round again: this round's fits, scored
                # against the model with the delay, are the record (none can be
                # significant)
                for f in st.fits:
                    f.score_against(chain_fit, True)
                self.rounds.append(sorted(st.fits, key=lambda f: -f.score))
                say(f"round {len(self.rounds)}: with the rig's delay the held-out "
                    "r.m.s. is within the floor: nothing more to explain")
                st.present = chain_fit  # (steps[-1], where there are steps)
                if not self.steps:
                    st.refit = st.present
                return "settled"
            # (the candidates of a next round: from the third on, those that gained)
            nxt = self.run(chain_fit, [None, *self.next_candidates(st.remaining, st.fits)],
                           f"round {len(self.rounds) + 1} (with the rig's delay)",
                           {f._added.effect: f for f in st.fits})
            st.present, st.fits, st.chain_fit = nxt[0], nxt[1:], None
            if st.present.sse_held > chain_fit.sse_held:
                st.present = chain_fit
            if not self.steps:
                st.refit = st.present
            return "again"
        if (chain_fit.significant and st.sig
                and not self.within_floor(max(st.sig, key=lambda f: f.score))):
            with_delay = self.runners_with_delay(st.present, small, st.sig)
            if with_delay is not None:
                st.fits = [f for f in st.fits if f._added.effect
                           != with_delay._added.effect] + [with_delay]
                st.sig, st.chain_fit = [with_delay], None
        return "on"

    def record_round(self, st: _Round, held_res: list[np.ndarray], floor: float,
                     small: bool) -> None:
        """The round's fits, significant first, into :attr:`rounds` (and the best three
        said)."""
        say = self.s.say
        self.rounds.append(sorted(st.fits, key=lambda f: (-f.significant, -f.score)))
        for f in self.rounds[-1][:3]:
            say(f"round {len(self.rounds)}: {f._added.effect} gain "
                f"{100 * f.score:+.1f} %, ΔBIC {f.delta_bic:.0f}"
                f"{' (significant)' if f.significant else ''}")
        if small:
            say(f"round {len(self.rounds)}: held-out r.m.s. {pooled_rms(held_res):.2f} N "
                f"is within the floor {floor:.2f} N: nothing more to explain")

    def next_round(self, st: _Round) -> bool:
        """The significant fit of the largest gain added, and the next round run on top
        of it; ``False`` where the search ends instead (four effects, none remaining, the
        residual within ``SEARCH_NOISE_FACTOR`` × the noise, or no candidate that gained).

        The next round: the present model refitted once more (the reference: a candidate
        must beat the present model's own further convergence, not only its last fit)
        and every remaining candidate on top of it (from the third round, those that
        gained most in this one), each also from its own fit of this round (joint_fit,
        the other order); the chain candidate again while it has not been taken."""
        say = self.s.say
        best = max(st.sig, key=lambda f: f.score)
        self.steps.append(best)
        st.remaining.remove(best._added.effect)
        say(f"added {best._added.effect} ({best._added.family}): held-out gain "
            f"{100 * best.score:.1f} %")
        if len(self.steps) >= self.max_effects or not st.remaining or self.settled(best):
            return False
        with_chain = [CHAIN] if st.chain_fit is not None else []
        following = self.next_candidates(st.remaining, st.fits)
        if not following and not with_chain:
            say(f"round {len(self.rounds)}: no remaining candidate gained on top of "
                "the effects: the search ends")
            return False
        nxt = self.run(best, [None, *with_chain, *following],
                       f"round {len(self.rounds) + 1}",
                       {f._added.effect: f for f in st.fits})
        st.present, st.fits = nxt[0], nxt[1:]
        if with_chain:
            st.chain_fit = st.fits.pop(0)
        if st.present.sse_held > best.sse_held:
            st.present = best
        return True

    def refine(self, step: StepFit, label: str) -> StepFit:
        """``step``, or, where the model's own integration is not converged on the records
        (:func:`~damper_emulator.diagnose.numerics.check_substep` against the noise level
        of ``step``'s held-out residual), ``step`` refitted on half the sub-step, which
        every later fit and the model after the diagnosis keep (once per diagnosis).

        The forward selection ends on the model's own sub-step; the model with the
        effects is refined before the backward elimination, which then weighs each effect
        on the finer sub-step, as do the rig's delay on the effects and the term
        discovery after.  An effect with a state of its own (a cavity, a short valve lag)
        leaves the most integration error (docs/model.md §2.1), which is no parameter's:
        on the model's sub-step the last rounds' candidates compete for it (free air kept
        beside a cavity and a term).  Refining each round instead doubled the rounds'
        time after the first effect."""
        s = self.s
        if self.refined is not None:
            return step
        noise = floor_level(s.held, step.residuals(s.held))[1]
        check = check_substep(step.model(), s.records, step.rig, noise)
        if check.converged:
            return step
        self.refined = check
        s.base = s.base.with_max_substep(check.max_substep_s / 2.0)
        s.say(f"{label}: halving the model's sub-step moves its force by "
              f"{check.change_n:.2f} N r.m.s. (noise level {check.noise_n:.2f} N): every "
              f"fit from here on {1e3 * s.cfg.numerics.max_substep_s:.3g} ms")
        (fine,) = self.run(step, [None], f"{label} (on half the sub-step)")
        return fine.replaces(step)

    def next_candidates(self, remaining: Sequence[str], fits: Sequence[StepFit]
                        ) -> list[str]:
        """The candidates of the next round: every remaining one for the second effect;
        from the third on, the :data:`LATER_ROUND_CANDIDATES` of them that gained most on
        the held-out files in this round (a candidate that gained nothing on top of two
        effects is not where a third is)."""
        if len(self.steps) < 2:
            return list(remaining)
        gained = {f._added.effect: f.score for f in fits if f.candidate is not None}
        ranked = sorted(remaining, key=lambda e: -gained.get(e, -math.inf))
        return [e for e in ranked[:LATER_ROUND_CANDIDATES] if gained.get(e, -1.0) > 0.0]

    def prune(self, refit: StepFit) -> None:
        """Backward elimination after the forward selection: each effect added before
        the last (the smallest held-out gain first) tried away, the model with the
        others fitted again from the present values; it goes where the present model
        gains less than ``MIN_SCORE`` on the held-out files against that fit.  The
        held-out files decide alone: ΔBIC weighs the parameters against the fit files,
        where beside the others an effect may add little (a cavity beside free air,
        ΔBIC +12) and still hold most of what the held-out files show (+69 %).  An
        effect taken early may only have stood in for part of one added later: a LuGre
        friction took 5.9 % beside a gas heat transfer before free air, which it half
        followed, was in; with the air in, the effects lost 67 % with it.  The last
        effect was significant on top of all the others when it was added.  A pair
        (found together, neither alone) is left as found.  The model without an effect
        that goes is the last step, scored against the step before it (``refit``, the
        first round's reference, where none is left)."""
        if len(self.steps) < 2 or self.pair_gain is not None:
            return
        for st in sorted(self.steps[:-1], key=lambda f: f.score):
            final = self.steps[-1]
            k = next(i for i, f in enumerate(self.steps) if f is st)
            keep = [j for j in range(len(final.candidates)) if j != k]
            without = StepFit(self.s.cfg, [final.candidates[j] for j in keep], {
                **final.out, "effect": None,
                **{key: [final.out[key][j] for j in keep]
                   for key in ("effects", "values", "std")}})
            name = st._added.effect
            (trial,) = self.run(without, [None], f"without {name}")
            weighed = dataclasses.replace(final)
            weighed.score_against(trial, False)
            goes = weighed.score < MIN_SCORE
            self.s.say(f"without {name}: the effects with it gain "
                       f"{100 * weighed.score:+.1f} % held out (ΔBIC "
                       f"{weighed.delta_bic:.0f}): " + ("it goes" if goes else "kept"))
            self.pruned.append(Pruned(name, st._added.family, weighed.score,
                                      weighed.delta_bic, goes, trial.rms_held_out))
            if not goes:
                continue
            # the model without it is the last step, as the effect it added last
            trial.out = {**trial.out, "effect": trial.candidates[-1].effect}
            del self.steps[k]
            trial.score_against(self.steps[-2] if len(self.steps) > 1 else refit, False)
            self.steps[-1] = trial

    def delay_on_effects(self) -> None:
        """The effects are in: the rig's delay on top of them, taken if significant
        (where it is estimated and was not taken before)."""
        steps = self.steps
        if not (self.s.estimate and steps
                and ACQUISITION_DELAY not in steps[-1].out["base_values"]):
            return
        (last,) = self.run(steps[-1], [CHAIN], "the rig's delay on the effects")
        last.score_against(steps[-1], self.within_floor(steps[-1]))
        self.s.say(f"the rig's delay {1e3 * last.out['base_values'][ACQUISITION_DELAY]:.3f}"
                   f" ms on the effects: gain {100 * last.score:+.1f} %, ΔBIC "
                   f"{last.delta_bic:.0f}{' (taken)' if last.significant else ''}")
        if last.significant:
            steps[-1] = last.replaces(steps[-1])
