"""``diagnose`` finds each family of the library after ``identify`` on the same files
(the truth's shorter protocol; tests/diagnose_support.py).  A module of its own so that
the test runner's workers share the diagnosis tests."""

from __future__ import annotations

import math

import pytest
from diagnose_support import (
    CHECKED,
    CONFUSABLE,
    NOISE_N,
    PARAMETER_TOLERANCE,
    identify_and_diagnose,
    pooled,
    truth_session,
)

from damper_emulator.diagnose.truth import EXAMPLE_EFFECTS
from damper_emulator.params import EXTENSION_FAMILIES

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("effect", list(EXAMPLE_EFFECTS))
def test_each_family_is_found_after_identify_on_the_same_files(effect):
    sheet, data = truth_session(effect)
    diag = identify_and_diagnose(sheet, data, [effect, *CONFUSABLE[effect]])
    assert diag.family == EXTENSION_FAMILIES[effect], (
        f"{effect}: diagnosed {diag.family}; first round "
        + ", ".join(f"{c.candidate.effect} {c.score:.3f}/{c.delta_bic:.0f}"
                    for c in diag.ranking))
    assert diag.effect == effect and diag.significant
    before = pooled(diag.rms_before, diag.held_out)
    after = pooled(diag.rms_after, diag.held_out)
    # the effect's residual is gone: down to the floor, and at least halved
    assert after <= max(diag.floor_n, 2.0 * NOISE_N) and after <= 0.5 * before, (
        effect, before, after, diag.floor_n)
    truth_params = EXAMPLE_EFFECTS[effect]["params"]
    main = diag.to_json()["effects"][0]
    for name in CHECKED.get(effect, tuple(truth_params)):
        assert main["parameters"][name] == pytest.approx(
            truth_params[name], rel=PARAMETER_TOLERANCE), (effect, name, main)
    # each fitted parameter's uncertainty is a number or undetermined (``None``, never
    # NaN); those the truth sets are determined.  A part the truth lacks (a stop's linear
    # stiffness or damping) sits at the no-force end of its range, where the data show
    # next to no slope: whether its σ is huge or undetermined is rounding.
    fitted = main["fitted"]
    assert all(f["std"] is None or math.isfinite(f["std"]) for f in fitted.values()), main
    determined = [n for n in (*CHECKED.get(effect, ()), *truth_params) if n in fitted]
    assert determined, (effect, sorted(fitted))
    for name in determined:
        assert fitted[name]["std"] is not None and fitted[name]["std"] > 0.0, (name, main)
    if effect == "cavitation":
        # its fit started from a re-identification with the friction at speed searched:
        # the truth's smooth seal has 1/tanh(4/5) = 1.5 times the quasi-static friction
        first = {f["effect"]: f for f in diag.to_json()["rounds"][0]}
        assert first["cavitation"]["reidentified"], first["cavitation"]
        assert first["cavitation"]["friction_factor"] == pytest.approx(1.5, abs=0.25)


