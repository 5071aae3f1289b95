"""Step 7 where the fit files leave an effect's law undetermined
(damper_emulator.diagnose.undetermined), on residuals built in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from damper_emulator.diagnose.base import make_record
from damper_emulator.diagnose.candidates import Candidate
from damper_emulator.diagnose.outcome import explained_fraction
from damper_emulator.diagnose.selection import weigh_effects
from damper_emulator.diagnose.undetermined import (
    MIN_UNDETERMINED_SHARE,
    determined_masks,
    explained_where,
    power_share,
    undetermined_findings,
)
from damper_emulator.dyno.measured import MeasuredData

NOISE_N = 4.0
STOP_M = 0.035


def _sine() -> MeasuredData:
    """A 40 mm, 3 Hz sine at 1 kHz: past the stops at ±35 mm for 2 × 2·acos(35/40)/(2π)
    = 32 % of each period."""
    t = np.arange(0.0, 4.0, 1e-3)
    x = 0.04 * np.sin(2 * math.pi * 3.0 * t)
    return MeasuredData(time=t, displacement=x, force=np.zeros_like(t), name="sine.csv")


def _stops(region: bool) -> Candidate:
    """An end-stop candidate whose law the files leave undetermined past the stops (or
    nowhere)."""
    return Candidate("end_stops", (), lambda v: {},
                     undetermined=(lambda d, v: np.abs(d.displacement) > v["at"])
                     if region else None,
                     limit="the stops' law of the speed is not the files' to tell")


class _Fitted:
    """What step 7 reads of a fitted model: its held-out residuals."""

    def __init__(self, residual: np.ndarray) -> None:
        self.residual = residual

    def residuals(self, records) -> list[np.ndarray]:
        return [self.residual]


def _case():
    held = make_record(_sine(), True)
    (determined,) = determined_masks([_stops(True)], [{"at": STOP_M}], [held])
    past = 1.0 - determined.mean()
    assert past == pytest.approx(2 * math.acos(STOP_M / 0.04) / math.pi, abs=0.01)
    noise = np.random.default_rng(3).normal(0.0, NOISE_N, determined.size)
    return held, determined, noise


def test_an_effect_whose_remainder_the_files_cannot_tell_is_kept():
    """The refitted model misses 100 N where the stops' law is determined and 300 N past
    them; the stops found take the 100 N and leave the 300 N: under 75 % of all the
    structured power, all of it where the files tell.  Dropped (``other``) without the
    regions, kept with them."""
    held, determined, noise = _case()
    before = noise + np.where(determined, 100.0, 300.0)
    after = noise + np.where(determined, 0.0, 300.0)
    assert explained_fraction([before], [after]) < 0.75
    assert explained_where([before], [after], [determined]) == pytest.approx(1.0, abs=0.01)
    assert power_share([after], [~determined]) >= MIN_UNDETERMINED_SHARE
    effect, refit = _Fitted(after), _Fitted(before)
    steps, closest, _, _ = weigh_effects(refit, [before], [effect], [held], 0.0, None)
    assert steps == [] and closest is effect
    steps, closest, _, _ = weigh_effects(refit, [before], [effect], [held], 0.0, None,
                                         determined=[determined])
    assert steps == [effect] and closest is None
    (found,) = undetermined_findings([_stops(True)], [{"at": STOP_M}], [held], [after])
    assert found.power == pytest.approx(1.0, abs=1e-3)
    assert found.samples == pytest.approx(1.0 - determined.mean())
    assert "not the files' to tell" in found.sentence()


def test_an_effect_that_leaves_structure_where_the_files_tell_is_dropped():
    """The same effect leaving 60 N of 100 N where its law is determined (64 % of the
    structured power explained): dropped with the regions too, and nothing is reported
    where the remainder is noise."""
    held, determined, noise = _case()
    before = noise + np.where(determined, 100.0, 0.0)
    after = noise + np.where(determined, 60.0, 0.0)
    steps, _, _, _ = weigh_effects(_Fitted(before), [before], [_Fitted(after)], [held],
                                   0.0, None, determined=[determined])
    assert steps == []
    assert undetermined_findings([_stops(True)], [{"at": STOP_M}], [held], [after]) == []


def test_no_region_no_mask():
    held = make_record(_sine(), True)
    assert determined_masks([_stops(False)], [{}], [held]) is None
    assert undetermined_findings([_stops(False)], [{}], [held], [np.zeros(held.counted)]) \
        == []
