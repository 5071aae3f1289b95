"""What a discovered term took from the model (``Diagnosis.term_moved``): the paper's
parameters its joint refit moved by more than ``TERM_MOVED_FACTOR`` from the model it
was added to, on given values; and a term's smooth sign read with eq 4's friction
(``Diagnosis.term_friction``).

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


def _with_parts(diag, parts):
    """The diagnosis's term made of ``parts``: (feature, coefficient) pairs."""
    import numpy as np

    term = diag.discovered
    term.features = [f for f, _ in parts]
    term.coefficients = np.array([c for _, c in parts])
    term.std = np.full(len(parts), 0.5)
    return diag


@pytest.mark.parametrize(("after", "term", "in_place"), [
    (5.97, 40.29, True),     # gave way, and the two hold what it held: the benchmark's case
    (40.0, 20.0, False),     # did not give way: a friction beside it
    (5.0, 100.0, False),     # gave way, but the two hold more than twice what it held
    (5.97, 25.0, False),     # gave way, and the two hold a third less than it held
])
def test_a_smooth_sign_part_is_read_with_eq_4s_friction(sport_cfg, after, term, in_place):
    from damper_emulator.diagnose.discovery import Feature, sign_feature
    from damper_emulator.diagnose.outcome import FRICTION_TOGETHER_TOLERANCE
    from damper_emulator.model.discovered import TERM_ACCELERATION, TERM_SIGN

    before = 43.8
    diag = _with_parts(_diagnosis(sport_cfg, {"friction_force_n": before},
                                  {"friction_force_n": after}),
                       [(Feature("ẍ", "kg", "acceleration", TERM_ACCELERATION), 2.0),
                        (sign_feature(TERM_SIGN, 4.26e-3), term)])
    tf = diag.term_friction()
    assert (tf.before, tf.after, tf.term, tf.sign_m_s) == (before, after, term, 4.26e-3)
    assert tf.together == pytest.approx(after + term)
    took = max(after / before, before / after) > TERM_MOVED_FACTOR
    assert took == ("friction_force_n" in diag.term_moved())
    assert tf.in_its_place is in_place is (
        took and abs((after + term) / before - 1) <= FRICTION_TOGETHER_TOLERANCE)
    doc = diag.discovered_json()["friction_with_model"]
    assert doc["together"] == pytest.approx(after + term) and doc["in_its_place"] is in_place
    assert ("smoothed over 4.26 mm/s" in doc["reading"]) is in_place
    from damper_emulator.diagnose.report import _discovery_lines

    text = "\n".join(_discovery_lines(diag))
    assert "**Its friction with eq 4's.**" in text and doc["reading"] in text


def test_no_friction_reading_without_a_smooth_sign_part(sport_cfg):
    """A term of the sign times the stroke is not eq 4's friction, nor is a mass."""
    from damper_emulator.diagnose.discovery import Feature, sign_feature
    from damper_emulator.model.discovered import TERM_ACCELERATION, TERM_STROKE_SIGN

    diag = _with_parts(_diagnosis(sport_cfg, {"friction_force_n": 43.8},
                                  {"friction_force_n": 5.97}),
                       [(Feature("ẍ", "kg", "acceleration", TERM_ACCELERATION), 2.0),
                        (sign_feature(TERM_STROKE_SIGN, 4.26e-3), 900.0)])
    assert diag.term_friction() is None
    assert diag.discovered_json()["friction_with_model"] is None
    assert _diagnosis(sport_cfg, {"friction_force_n": 43.8}, {"friction_force_n": 5.97},
                      significant=False).term_friction() is None
