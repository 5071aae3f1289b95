"""What a discovered term took from the model (``Diagnosis.term_moved``): the paper's
parameters its joint refit moved by more than ``TERM_MOVED_FACTOR`` from the model it
was added to, on given values.

The real case is the benchmark's ``sport:cavitation+valve_lag`` on the refined sub-step:
a smooth friction term of 40 N where eq 4's friction fell from 44 N to 6 N, the truth's
seal (43.7 N tanh(ẋ / 5 mm/s)) in another form."""

from __future__ import annotations

import pytest

from damper_emulator.diagnose.base import (
    ACQUISITION_DELAY,
    QUASI_STATIC_FRICTION_RATIO,
    TERM_PREFIX,
)
from damper_emulator.diagnose.discovery import Discovery
from damper_emulator.diagnose.outcome import TERM_MOVED_FACTOR, Diagnosis, StepFit
from damper_emulator.model.compressible import DamperModel


def _diagnosis(cfg, before, after, significant=True, refitted=True):
    step = StepFit(cfg, [], {"effect": None, "effects": [], "values": [], "std": [],
                             "base_values": before, "held": {}, "fit": {}})
    term = Discovery(ran=True, reason="", significant=significant, base_values=after,
                     model=DamperModel(cfg) if refitted else None)
    return Diagnosis(family="cavitation", effect="cavitation", significant=True,
                     rms_before={}, rms_after={}, ranking=[], held_out=[],
                     structure_before=0.0, structure_after=0.0, seconds=0.0,
                     steps=[step], discovered=term)


def test_the_parameters_the_term_moved_beyond_the_factor_are_named_with_both_values(
        sport_cfg):
    f = TERM_MOVED_FACTOR
    before = {"friction_force_n": 43.8, "gas_pressure_static_pa": 1.5e6,
              "rebound.k_port": 1.0e12, "compression.k_port": 2.0e11,
              QUASI_STATIC_FRICTION_RATIO: 0.68, ACQUISITION_DELAY: 1e-4,
              f"{TERM_PREFIX}0": 1.0}
    after = {"friction_force_n": 5.97, "gas_pressure_static_pa": 1.6e6,
             "rebound.k_port": 1.0e12 * f,               # exactly the factor: not beyond
             "compression.k_port": 2.0e11 * 1.01 * f,    # beyond it, upwards
             QUASI_STATIC_FRICTION_RATIO: 1e-13, ACQUISITION_DELAY: 1e-3,
             f"{TERM_PREFIX}0": 40.0}
    moved = _diagnosis(sport_cfg, before, after).term_moved()
    assert moved == {"friction_force_n": (43.8, 5.97),
                     "compression.k_port": (2.0e11, pytest.approx(2.0e11 * 1.01 * f))}


def test_nothing_is_named_without_a_significant_term(sport_cfg):
    before, after = {"friction_force_n": 43.8}, {"friction_force_n": 5.97}
    assert _diagnosis(sport_cfg, before, after, significant=False).term_moved() == {}
    assert _diagnosis(sport_cfg, before, after, refitted=False).term_moved() == {}


def test_the_report_names_what_the_term_took_beside_the_term(sport_cfg):
    import numpy as np

    from damper_emulator.diagnose.discovery import Feature
    from damper_emulator.diagnose.report import _discovery_lines

    diag = _diagnosis(sport_cfg, {"friction_force_n": 43.8}, {"friction_force_n": 5.97})
    term = diag.discovered
    term.features = [Feature("tanh(ẋ / 4.26 mm/s)", "N", "friction", 0)]
    term.coefficients, term.std = np.array([40.29]), np.array([0.5])
    text = "\n".join(_discovery_lines(diag))
    assert "**What the term took from the model.**" in text
    assert f"more than {TERM_MOVED_FACTOR:g}×" in text and "`friction_force_n` 43.8 → 5.97" in text
    diag.steps[0].out["base_values"] = {"friction_force_n": 6.5}  # the term took nothing
    assert "What the term took" not in "\n".join(_discovery_lines(diag))
