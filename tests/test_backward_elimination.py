"""The backward elimination after the forward selection (``LibraryRounds.prune``): which
effect is tried away, in what order, what goes, and what the diagnosis is left with.

The fits are given, not computed (a real case is the benchmark's
``sport:air_entrainment>gas_heat_transfer``, where a LuGre friction taken second stood
in for part of the free air taken third): each model's held-out and fit figures are set,
so that the rule is checked against figures worked out by hand here."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from diagnose_support import truth_session

from damper_emulator.diagnose.candidates import candidates
from damper_emulator.diagnose.outcome import MIN_SCORE, StepFit
from damper_emulator.diagnose.rounds import LibraryRounds

#: held-out samples and fit samples of every model below
N_HELD = 1000
N_FIT = 5000


@pytest.fixture(scope="module")
def library():
    sheet, data = truth_session(None)
    return sheet, {c.effect: c for c in candidates(sheet, data[:2])}


def _fit(sheet, library, effects, held_rms, fit_mse, added=True) -> StepFit:
    """A fit of the model with ``effects``: its held-out r.m.s. [N] on one file and its
    mean square on one fit file."""
    cands = [library[e] for e in effects]
    return StepFit(sheet, cands, {
        "effect": effects[-1] if added and effects else None, "effects": list(effects),
        "values": [{p.name: p.start for p in c.parameters} for c in cands],
        "std": [{} for _ in cands], "base_values": {},
        "held": {"sine.csv": {"rms": held_rms, "sse": held_rms ** 2 * N_HELD}},
        "fit": {"chirp.csv": {"n": N_FIT, "rho": 0.0, "mse": fit_mse}},
        "seconds": 0.0, "evaluations": 0})


def _two_steps(sheet, library, first, second, figures):
    """The refitted paper's model and two steps (``first``, then ``second`` on top of it),
    each scored against the one before: ``figures`` their (held-out r.m.s., fit mean
    square) in that order."""
    (r_rms, r_ms), (a_rms, a_ms), (b_rms, b_ms) = figures
    refit = _fit(sheet, library, [], r_rms, r_ms)
    a = _fit(sheet, library, [first], a_rms, a_ms)
    b = _fit(sheet, library, [first, second], b_rms, b_ms)
    a.score_against(refit, False)
    b.score_against(a, False)
    return refit, a, b


def _rounds(sheet, steps, refits):
    """``LibraryRounds`` whose fits are ``refits`` (the model with the effects given as
    a tuple, refitted); ``tried`` collects the effects of every model refitted."""
    said, tried = [], []
    rounds = LibraryRounds(SimpleNamespace(cfg=sheet, say=said.append), None, None, 4)
    rounds.steps = list(steps)

    def run(present, effects, label, before=None):
        assert effects == [None] and present.out["effect"] is None
        tried.append(tuple(present.effects))
        fit = refits[tuple(present.effects)]
        return [fit]

    rounds.run = run
    return rounds, said, tried


def test_an_effect_that_stood_in_for_a_later_one_goes_and_the_first_stays(library):
    sheet, lib = library
    refit = _fit(sheet, lib, [], 30.0, 900.0)
    a = _fit(sheet, lib, ["gas_heat_transfer"], 20.0, 400.0)
    b = _fit(sheet, lib, ["gas_heat_transfer", "lugre_friction"], 18.0, 380.0)
    c = _fit(sheet, lib, ["gas_heat_transfer", "lugre_friction", "air_entrainment"],
             8.3, 30.0)
    a.score_against(refit, False)
    b.score_against(a, False)
    c.score_against(b, False)
    assert min(a.score, c.score) > b.score >= MIN_SCORE  # all three were significant
    # without the friction the other two leave less held out; without the heat transfer
    # the air alone leaves far more
    a_c = _fit(sheet, lib, ["gas_heat_transfer", "air_entrainment"], 5.0, 32.0,
               added=False)
    c_alone = _fit(sheet, lib, ["air_entrainment"], 15.0, 100.0, added=False)
    rounds, said, tried = _rounds(sheet, [a, b, c], {
        ("gas_heat_transfer", "air_entrainment"): a_c, ("air_entrainment",): c_alone})
    rounds.prune(refit)
    # the smallest gain first; the last effect is never tried
    assert tried == [("gas_heat_transfer", "air_entrainment"), ("air_entrainment",)]
    assert [s._added.effect for s in rounds.steps] == ["gas_heat_transfer",
                                                        "air_entrainment"]
    last = rounds.steps[-1]
    assert last is a_c and last.candidate.effect == "air_entrainment"
    # scored against the step before it now: 1 - 5/20
    assert last.score == pytest.approx(0.75) and last.significant
    assert last.rms_held_out_before == {"sine.csv": 20.0}
    went, kept = rounds.pruned
    assert (went.effect, went.went) == ("lugre_friction", True)
    assert went.gain == pytest.approx(1.0 - 8.3 / 5.0)
    assert went.rms_held_out_without == {"sine.csv": 5.0}
    assert (kept.effect, kept.went) == ("gas_heat_transfer", False)
    assert kept.gain == pytest.approx(1.0 - 5.0 / 15.0)
    assert any("without lugre_friction" in m and "it goes" in m for m in said), said


def test_effects_that_each_gain_beside_the_others_all_stay(library):
    sheet, lib = library
    refit, a, b = _two_steps(sheet, lib, "valve_lag", "lugre_friction",
                             ((30.0, 900.0), (15.0, 300.0), (5.0, 20.0)))
    alone = _fit(sheet, lib, ["lugre_friction"], 25.0, 700.0, added=False)
    rounds, _, tried = _rounds(sheet, [a, b], {("lugre_friction",): alone})
    rounds.prune(refit)
    assert tried == [("lugre_friction",)]
    assert rounds.steps == [a, b] and b.score == pytest.approx(1.0 - 5.0 / 15.0)
    (kept,) = rounds.pruned
    assert not kept.went and kept.gain == pytest.approx(0.8)


def test_the_first_effect_goes_too_where_a_later_one_holds_all_it_did(library):
    sheet, lib = library
    refit, a, b = _two_steps(sheet, lib, "series_compliance", "valve_lag",
                             ((30.0, 900.0), (20.0, 300.0), (5.0, 20.0)))
    # the valve lag alone leaves as little: the compliance gains 1 % beside it
    alone = _fit(sheet, lib, ["valve_lag"], 5.0 / 0.99, 20.5, added=False)
    rounds, _, _ = _rounds(sheet, [a, b], {("valve_lag",): alone})
    rounds.prune(refit)
    (only,) = rounds.steps
    assert only is alone and only.candidate.effect == "valve_lag"
    # the first step now: scored against the refitted paper's model
    assert only.score == pytest.approx(1.0 - (5.0 / 0.99) / 30.0)
    assert rounds.pruned[0].went and math.isclose(rounds.pruned[0].gain, 0.01, rel_tol=1e-9)


def test_a_pair_and_a_single_effect_are_left_as_found(library):
    sheet, lib = library
    refit, a, b = _two_steps(sheet, lib, "bypass_groove", "viscosity_temperature",
                             ((30.0, 900.0), (29.0, 300.0), (5.0, 20.0)))
    rounds, _, tried = _rounds(sheet, [a, b], {})
    rounds.pair_gain = 0.8
    rounds.prune(refit)
    assert rounds.steps == [a, b] and not tried and not rounds.pruned
    rounds, _, tried = _rounds(sheet, [a], {})
    rounds.prune(refit)
    assert rounds.steps == [a] and not tried


def test_the_held_out_files_decide_not_the_fit_files(library):
    """Beside the others an effect may add nothing on the fit files (ΔBIC > 0: its
    parameters cost more than they gain there) and hold most of what the held-out files
    show: it stays (the benchmark's cavity beside free air, +69 %, ΔBIC +12)."""
    sheet, lib = library
    refit, a, b = _two_steps(sheet, lib, "cavitation", "air_entrainment",
                             ((400.0, 900.0), (150.0, 100.0), (100.0, 90.0)))
    alone = _fit(sheet, lib, ["air_entrainment"], 100.0 / 0.31, 90.0, added=False)
    rounds, _, _ = _rounds(sheet, [a, b], {("air_entrainment",): alone})
    rounds.prune(refit)
    (kept,) = rounds.pruned
    assert kept.delta_bic > 0 and kept.gain == pytest.approx(0.69)
    assert not kept.went and rounds.steps == [a, b]
