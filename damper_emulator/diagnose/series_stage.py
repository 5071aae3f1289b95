"""The series stage of a diagnosis (:func:`follow_series`): what moves from file to file
over the test series, weighed with the statistics of :mod:`damper_emulator.diagnose.
series` on the identified model (or on the paper's model refitted with the rig's delay),
and on refits of the paper's model with a kind per file where the identification took
it or a zero and a gas charge are to be told apart; what it takes is fitted per file
beside every later fit and score."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from damper_emulator.acquisition.chain import relative_delay
from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.base import ACQUISITION_DELAY, PerFile
from damper_emulator.diagnose.candidates import temperature_stats
from damper_emulator.diagnose.outcome import StepFit, noise_level
from damper_emulator.diagnose.rounds import LibraryRounds
from damper_emulator.diagnose.series import (
    KINDS,
    MIN_SERIES_EXPLAINED,
    RIG_OR_DAMPER_BIC,
    SERIES_MAX_DELTA_BIC,
    SPEED_CONFOUNDED,
    FileColumns,
    SeriesResult,
    alone,
    contender,
    file_columns,
    follows_series,
    refined,
    refit_evidence,
    select,
    series_positions,
    speed_ordered,
)
from damper_emulator.diagnose.session import Session
from damper_emulator.model.compressible import DamperModel

__all__ = ["follow_series"]


@dataclass
class _Series:
    """What the series stage works with: the records' places, the reference file, each
    file's noise level and the kinds tried."""

    session: Session
    positions: dict[str, float]
    reference: str
    sigmas: dict[str, float]
    kinds: list[str]
    #: the first look's delay of the force [s] where the chain is estimated, else None
    delay: float | None = None
    #: the series' order follows the files' speeds (``series.speed_ordered``)
    by_speed: bool = False

    def columns(self, model: DamperModel, rig: RigParams | None) -> list[FileColumns]:
        return file_columns(model, rig, self.session.records, self.reference, self.sigmas)

    def residuals(self, fit: StepFit, per_file: Mapping[str, PerFile]) -> list[np.ndarray]:
        """``fit``'s residual on every file, ``per_file`` projected out."""
        self.session.with_per_file(per_file)
        out = fit.residuals(self.session.records)
        self.session.with_per_file({})
        return out


def follow_series(session: Session, order: Sequence[str] | None,
                  rounds: LibraryRounds, rig: RigParams | None = None,
                  start: StepFit | None = None) -> SeriesResult:
    """Stage 2: what moves from file to file over the series, on the identified model's
    residual of every file (:func:`~damper_emulator.diagnose.series.select`); what it
    takes is fitted per file beside every later fit and score (``session.per_file``).
    A zero or a gas charge, or a kind that fails only because the identification
    absorbed it (:func:`~damper_emulator.diagnose.series.contender`), is weighed on the
    paper's model refitted with it per file (:func:`_refitted_series`), whose parameters
    the later fits then start from.  The oil's valve scale is not tried where the files
    carry a temperature column: a column that moves is the library's thermal candidate's,
    one that does not says the oil did not warm.  ``rig``: a first look at the chain
    (:func:`~damper_emulator.diagnose.measurement.screen_delay`) the identified model's
    residual is taken through; ``start``: a fit to weigh the series on in the identified
    model's place (the paper's model refitted with the rig's delay)."""
    records = session.records
    positions = series_positions(records, order)
    temps = temperature_stats([r.data for r in records])
    by_speed = speed_ordered(records, positions)
    kinds = [k.name for k in KINDS
             if not (k.name == "valve_scale" and temps is not None)
             and not (by_speed and k.name in SPEED_CONFOUNDED)]
    if by_speed:
        session.say("series: the files' order follows their speeds: a friction or a "
                    "valve scale that changes over the series cannot be told from one "
                    "that changes with the speed, and is not weighed as a drift")
    ctx = _Series(session, positions, min(positions, key=lambda n: positions[n]),
                  {r.name: noise_level(session.base_res[r.name]) for r in records},
                  kinds, relative_delay(rig) if rig is not None and session.estimate
                  else None, by_speed)
    model = session.base
    if start is not None:
        model, rig = start.model(), start.rig
        if rig is not None:
            ctx.delay = relative_delay(rig)
    files = ctx.columns(model, rig)
    result = select(files, positions, ctx.kinds, model, by_speed=by_speed)
    lead = result.taken[0].kind.name if result.taken else contender(result)
    if lead is not None and (not result.taken or lead in ("zero", "gas")):
        again = _refitted_series(ctx, rounds, files, result, lead)
        if again is not None:
            result, files, model, rig = again
        elif not result.taken:
            session.say("series: nothing moves from file to file beyond the noise")
    refined(model, rig, records, files, result)
    for d in result.taken:
        session.say(f"series: {d.kind.doc} moves over the files (ΔBIC {d.delta_bic:.0f}, "
                    f"{d.kind.cause}): " + ", ".join(f"{k} {v:.4g}"
                                                     for k, v in d.values().items())
                    + f" {d.kind.unit}" + (f"; a change of the {d.ambiguous_with} fits "
                                           "nearly as well" if d.ambiguous_with else ""))
    if not result.taken and lead is None:
        session.say("series: nothing moves from file to file beyond the noise")
    session.with_per_file(result.per_file(files))
    return result


def _refitted_series(ctx: _Series, rounds: LibraryRounds, files: list[FileColumns],
                     screened: SeriesResult, lead: str
                     ) -> tuple[SeriesResult, list[FileColumns], DamperModel,
                                RigParams | None] | None:
    """The series weighed again on the paper's model refitted with ``lead`` per file:
    where the screen did not take it (a contender), it must explain
    :data:`~damper_emulator.diagnose.series.MIN_SERIES_EXPLAINED` of what the refit
    without it leaves (:func:`~damper_emulator.diagnose.series.refit_evidence`); a zero
    and a gas charge are each refitted, and the one of the lower BIC taken (within
    ``RIG_OR_DAMPER_BIC``: the gas where it follows the series).  Returns the series at
    the refit, its files' columns, the refitted model and its chain; ``None``: not
    taken."""
    say = ctx.session.say
    partner = {"zero": "gas", "gas": "zero"}.get(lead)
    if partner is not None and partner not in ctx.kinds:
        partner = None
    names = [lead, *([partner] if partner else [])]
    per_files = {n: alone(n, files) for n in names}
    # behind an estimated chain, the refits free its delay from the first look's
    start = ({ACQUISITION_DELAY: float(ctx.delay)} if ctx.delay is not None else None)
    tasks = [rounds.task(None, None, start=start)] if not screened.taken else []
    for n in names:
        ctx.session.with_per_file(per_files[n])
        tasks.append(rounds.task(None, None, start=start))
    ctx.session.with_per_file({})
    say(f"series: the paper's model refitted with {' and with '.join(names)} per file"
        + (" and without" if not screened.taken else ""))
    fits = rounds.execute(None, tasks, "series (the paper's model refitted)")
    refits = dict(zip(names, fits[len(fits) - len(names):]))
    res = {n: ctx.residuals(refits[n], per_files[n]) for n in names}
    sigmas = [ctx.sigmas[r.name] for r in ctx.session.records]

    def columns_of(n: str) -> int:
        return sum(p.columns.shape[1] + p.gain for p in per_files[n].values())
    evidence = {}
    if not screened.taken:
        without = ctx.residuals(fits[0], {})
        for n in names:
            evidence[n] = refit_evidence(sigmas, without, res[n], columns_of(n))
            say(f"series: with {n} per file the refit leaves "
                f"{100 * (1 - evidence[n][1]):.0f} % of the structure it leaves without "
                f"(ΔBIC {evidence[n][0]:.0f})")
        names = [n for n in names if evidence[n][0] <= SERIES_MAX_DELTA_BIC
                 and evidence[n][1] >= MIN_SERIES_EXPLAINED]
        if not names:
            return None
    chosen, ambiguous = names[0], None
    if len(names) == 2:
        dbic = refit_evidence(sigmas, res[names[0]], res[names[1]],
                              columns_of(names[1]) - columns_of(names[0]))[0]
        say(f"series: {names[1]} against {names[0]} per file, both refitted: "
            f"ΔBIC {dbic:.0f}")
        if abs(dbic) < RIG_OR_DAMPER_BIC:
            gas_model = refits["gas"].model()
            gas = select(ctx.columns(gas_model, refits["gas"].rig), ctx.positions,
                         ctx.kinds, gas_model, first="gas", by_speed=ctx.by_speed).taken[0]
            chosen = "gas" if follows_series(gas, len(files)) else "zero"
            ambiguous = "zero" if chosen == "gas" else "gas"
        elif dbic < 0.0:
            chosen = names[1]
    refit = refits[chosen]
    model = refit.model()
    files = ctx.columns(model, refit.rig)
    # its evidence: against the refit without it, or as the screen weighed it
    screen = next((t for t in screened.tried if t["round"] == 1 and t["kind"] == chosen),
                  None)
    first_evidence = (evidence.get(chosen)
                      or ((screen["delta_bic"], screen["explained"]) if screen is not None
                          else (0.0, 0.0)))
    result = select(files, ctx.positions, ctx.kinds, model, first=chosen,
                    evidence=first_evidence, by_speed=ctx.by_speed)
    result.taken[0].ambiguous_with = ambiguous
    # the later fits start from the refit's paper's parameters (the delay competes in
    # the rounds as ever)
    ctx.session.base_values.update({k: v for k, v in refit.out["base_values"].items()
                                    if k != ACQUISITION_DELAY})
    return result, files, model, refit.rig
