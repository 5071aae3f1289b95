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
