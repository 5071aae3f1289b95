"""The diagnosis's measure of the model's own integration error (``diagnose.numerics``),
against that error itself: the same model on sub-steps 16 times shorter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from damper_emulator.diagnose.base import make_record
from damper_emulator.diagnose.numerics import SUBSTEP_NOISE_FRACTION, check_substep
from damper_emulator.diagnose.truth import example_config
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.dyno.protocols import chirp, sine
from damper_emulator.model.compressible import DamperModel, simulate


def _records(model: DamperModel) -> list:
    """A 3 Hz, 50 mm sine and the paper's chirp at 1 kHz, their force the model's
    own (the check does not read it)."""
    out = []
    for name, (t, x, v) in (("sine_3hz", sine(3.0, 0.05, cycles=2, rate_hz=1000)),
                            ("chirp", chirp(rate_hz=1000))):
        f = simulate(model, t, x, v).force_n
        out.append(make_record(MeasuredData(t, x, f, v, name=name), held_out=False))
    return out


def _error(model: DamperModel, records: list) -> float:
    """The pooled r.m.s. of the model's force against the same on 16× shorter sub-steps."""
    fine = model.with_max_substep(model.cfg.numerics.max_substep_s / 16)
    d = np.concatenate([(r.simulate(model) - r.simulate(fine))[r.start:] for r in records])
    return math.sqrt(float(d @ d) / d.size)


@pytest.mark.parametrize("effects", [None, "cavitation", "valve_lag",
                                     ("cavitation", "valve_lag")])
def test_the_change_on_halving_the_sub_step_measures_the_integration_error(sport_cfg,
                                                                           effects):
    """The change on halving is the error's measure: the true error (against 16× shorter
    sub-steps) lies between it and twice it (second order: 4/3 of it; an event within a
    sub-step: up to 2); with a cavity and a valve lag it is many times the paper's
    model's, whose change is within half of a 4 N noise."""
    model = DamperModel(example_config(effects, sport_cfg))
    records = _records(model)
    found = check_substep(model, records, None, noise_n=4.0)
    err = _error(model, records)
    assert found.max_substep_s == sport_cfg.numerics.max_substep_s
    assert found.change_n <= err <= 2.0 * found.change_n
    assert set(found.per_file) == {"sine_3hz", "chirp"}
    assert min(found.per_file.values()) <= found.change_n <= max(found.per_file.values())
    if effects is None:
        assert found.converged and found.change_n < SUBSTEP_NOISE_FRACTION * 4.0
    if effects == ("cavitation", "valve_lag"):
        assert not found.converged
        assert "numerics.max_substep_s" in found.sentence()
        # the remedy it names works: on half the sub-step the change is a third or less
        again = check_substep(model.with_max_substep(found.max_substep_s / 2), records,
                              None, noise_n=4.0)
        assert again.change_n < found.change_n / 3.0


def _step(session, effects, values):
    """A step of the rounds with ``effects`` at ``values`` (by candidate parameter name;
    the candidate's start where none is given) on the identified paper's parameters."""
    from damper_emulator.diagnose.outcome import StepFit

    cands = [session.candidates[e] for e in effects]
    vals = [{p.name: values.get(p.name, p.start) for p in c.parameters} for c in cands]
    return StepFit(session.cfg, cands, {
        "effect": effects[-1] if effects else None, "effects": list(effects),
        "values": vals, "std": [{} for _ in cands], "base_values": dict(session.base_values),
        "held": {}, "fit": {}, "seconds": 0.0, "evaluations": 0})


def test_the_rounds_refit_a_step_on_half_the_sub_step_once_where_its_integration_fails():
    """``LibraryRounds.refine`` on the truth's own session (a cavity and a 4 ms valve lag
    behind the sport damper): the paper's model alone is within the check and stays as it
    is; the model with the cavity and the lag at the truth's values is not, and is fitted
    again (a real joint fit) on half the sub-step, which the session keeps for every
    later fit; a second failing step is not refined again."""
    from diagnose_support import FEW_NFEV, truth_session

    from damper_emulator.diagnose.pool import LocalPool
    from damper_emulator.diagnose.rounds import LibraryRounds
    from damper_emulator.diagnose.session import prepare

    sheet, data = truth_session(("cavitation", "valve_lag"))
    effects = ["cavitation", "valve_lag"]
    said: list[str] = []
    session = prepare(DamperModel(sheet), data[:2], data[2:], effects, 1, FEW_NFEV,
                      said.append)
    h = session.cfg.numerics.max_substep_s
    truth = {"cavitation_pressure_pa": 2.0e4, "time_constant_s": 4e-3}
    with LocalPool(1) as local:
        rounds = LibraryRounds(session, local, None, 4)
        paper = _step(session, [], {})
        assert rounds.refine(paper, "round 1") is paper and rounds.refined is None
        assert session.cfg.numerics.max_substep_s == h and not said
        step = _step(session, effects, truth)
        step.score, step.significant = 0.7, True
        fine = rounds.refine(step, "round 2")
        check = rounds.refined
        assert check is not None and not check.converged and check.max_substep_s == h
        assert session.cfg.numerics.max_substep_s == h / 2
        assert fine is not step and fine.cfg.numerics.max_substep_s == h / 2
        assert fine.model().cfg.numerics.max_substep_s == h / 2
        assert fine.effects == effects and fine.candidate is step.candidate
        assert (fine.score, fine.significant) == (0.7, True)
        assert fine.evaluations > 0 and set(fine.rms_held_out) == {r.name for r in session.held}
        assert any(f"every fit from here on {1e3 * h / 2:.3g} ms" in s for s in said)
        again = _step(session, effects, truth)
        assert rounds.refine(again, "round 3") is again
        assert session.cfg.numerics.max_substep_s == h / 2
