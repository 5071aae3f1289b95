"""Below the floor, an effect that trades one identification file's fit for the others'
is not significant (``StepFit.refuse_trade``, used by ``LibraryRounds.score_round``).

The fits are given, not computed (the real case is the benchmark's
``van:stops_exponential/speeds``, where a valve lag of 48 µs took part of the end stops'
form error): each file's mean square is set, and the effective ΔBIC each file gives is
worked out here from ``n_eff ln(ms_after / ms_before)``, ``n_eff = n (1 − ρ)/(1 + ρ)``."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from diagnose_support import truth_session

from damper_emulator.diagnose.candidates import candidates
from damper_emulator.diagnose.outcome import MAX_FILE_BIC_RISE, StepFit
from damper_emulator.diagnose.rounds import LibraryRounds, _Round

#: samples and lag-1 autocorrelation of each identification file below
N_FIT, RHO = 5000, 0.9
N_EFF = N_FIT * (1.0 - RHO) / (1.0 + RHO)  # 263.2
#: the present model's mean square on both identification files [N²]
MS_BEFORE = 100.0
#: one file's mean-square ratio whose ΔBIC is just above / below MAX_FILE_BIC_RISE
WORSE = math.exp(1.2 * MAX_FILE_BIC_RISE / N_EFF)
SLIGHTLY_WORSE = math.exp(0.8 * MAX_FILE_BIC_RISE / N_EFF)


@pytest.fixture(scope="module")
def library():
    sheet, data = truth_session(None)
    return sheet, {c.effect: c for c in candidates(sheet, data[:2])}


def _fit(sheet, library, effects, held_rms, ms_a, ms_b) -> StepFit:
    """A fit of the model with ``effects``: its held-out r.m.s. [N] and its mean squares
    on the two identification files a and b [N²]."""
    cands = [library[e] for e in effects]
    return StepFit(sheet, cands, {
        "effect": effects[-1] if effects else None, "effects": list(effects),
        "values": [{p.name: p.start for p in c.parameters} for c in cands],
        "std": [{} for _ in cands], "base_values": {},
        "held": {"road.csv": {"rms": held_rms, "sse": held_rms ** 2 * 1000}},
        "fit": {name: {"n": N_FIT, "rho": RHO, "mse": ms, "rms": math.sqrt(ms)}
                for name, ms in (("a.csv", ms_a), ("b.csv", ms_b))},
        "seconds": 0.0, "evaluations": 0})


def test_the_worst_file_and_its_bic_are_those_worked_out_by_hand(library):
    sheet, lib = library
    present = _fit(sheet, lib, ["end_stops"], 13.0, MS_BEFORE, MS_BEFORE)
    f = _fit(sheet, lib, ["end_stops", "valve_lag"], 12.0, 0.8 * MS_BEFORE,
             1.3 * MS_BEFORE)
    name, rise = f.worst_file(present)
    assert name == "b.csv"
    assert rise == pytest.approx(N_EFF * math.log(1.3), rel=1e-12)


@pytest.mark.parametrize(("ratio_b", "refused"), [(WORSE, True), (SLIGHTLY_WORSE, False),
                                                  (0.9, False)])
def test_a_significant_fit_that_makes_a_file_worse_beyond_the_rise_is_refused(
        library, ratio_b, refused):
    sheet, lib = library
    present = _fit(sheet, lib, ["end_stops"], 13.0, MS_BEFORE, MS_BEFORE)
    # file a much better: the whole fit is significant (gain 7.7 %, ΔBIC far below −10)
    f = _fit(sheet, lib, ["end_stops", "valve_lag"], 12.0, 0.5 * MS_BEFORE,
             ratio_b * MS_BEFORE)
    f.score_against(present, False)
    assert f.significant and f.delta_bic < -100.0
    assert (f.refuse_trade(present) is not None) is refused
    assert f.significant is not refused
    doc = f.to_json()
    if refused:
        assert doc["trades_file"]["file"] == "b.csv"
        assert doc["trades_file"]["delta_bic"] == pytest.approx(
            N_EFF * math.log(ratio_b), rel=1e-12)
    else:
        assert "trades_file" not in doc and f.trades is None


def test_a_fit_that_was_not_significant_is_not_said_to_trade(library):
    sheet, lib = library
    present = _fit(sheet, lib, ["end_stops"], 13.0, MS_BEFORE, MS_BEFORE)
    f = _fit(sheet, lib, ["end_stops", "valve_lag"], 12.9, MS_BEFORE, WORSE * MS_BEFORE)
    f.score_against(present, False)
    assert not f.significant
    assert f.refuse_trade(present) is None and f.trades is None


def _held(force_rms: float, residual: np.ndarray):
    """One held-out record whose force has ``force_rms`` and whose present residual is
    ``residual`` (what ``floor_level`` and ``score_round`` read of it)."""
    n = residual.size
    force = force_rms * math.sqrt(2.0) * np.sin(np.linspace(0.0, 40.0 * math.pi, n))
    return SimpleNamespace(data=SimpleNamespace(force=force), start=0)


@pytest.mark.parametrize(("structure_rms", "below"), [(4.5, True), (50.0, False)])
def test_score_round_refuses_a_trade_only_below_the_first_floor(library, structure_rms,
                                                                  below):
    """1 N of white noise and a slow structure of ``structure_rms`` left by the present
    model, 2000 N of force: the first floor is 10 N (0.5 % of the force), 3× the noise
    about 3 N.  At 4.5 N of structure the residual is within the floor and the search
    goes on below it: the trading fit is refused.  At 50 N, above the floor, the same fit
    is significant: what is left is not a first effect's small form error."""
    sheet, lib = library
    n = 4000
    residual = (np.random.default_rng(7).normal(0.0, 1.0, n) + structure_rms
                * math.sqrt(2.0) * np.sin(np.linspace(0.0, 6.0 * math.pi, n)))
    rms = float(np.sqrt(np.mean(residual ** 2)))
    present = _fit(sheet, lib, ["end_stops"], rms, MS_BEFORE, MS_BEFORE)
    present.residuals = lambda records: [residual]
    f = _fit(sheet, lib, ["end_stops", "valve_lag"], 0.9 * rms, 0.5 * MS_BEFORE,
             WORSE * MS_BEFORE)
    said: list[str] = []
    session = SimpleNamespace(cfg=sheet, say=said.append, held=[_held(2000.0, residual)])
    rounds = LibraryRounds(session, None, None, 4)
    rounds.steps = [present]
    st = _Round(present, present, [f], None, [])
    _, floor, small = rounds.score_round(st)
    assert not small and floor < rms  # the search goes on in both cases
    if below:
        assert st.sig == [] and f.trades == ("b.csv", pytest.approx(
            N_EFF * math.log(WORSE), rel=1e-12))
        assert any("trades files" in s for s in said)
    else:
        assert st.sig == [f] and f.trades is None and not said
