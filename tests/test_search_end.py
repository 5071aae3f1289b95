"""Where the library's search ends (``LibraryRounds.settled``): the held-out residual within
``SEARCH_NOISE_FACTOR`` times its noise where the fit files determine the laws of the
effects found.

The residuals are given, not computed (the real case is the benchmark's
``van:stops_hydraulic/paper``, whose fit files reach the stops only in the quasi-static
test, while a held-out sine enters them at speed): white noise of 1 N, and a structure of
50 N placed by the test where the sines are past the stops at more than 0.1 m/s, far
above the fit files' speed there, and elsewhere."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from diagnose_support import truth_session

from damper_emulator.diagnose.base import make_record
from damper_emulator.diagnose.candidates import candidates
from damper_emulator.diagnose.outcome import SEARCH_NOISE_FACTOR, StepFit
from damper_emulator.diagnose.rounds import LibraryRounds

#: the stops of the fits below [m]: the held-out sines reach ±50 mm
STOP_M = 0.03
#: the structure's size [N] and the speed above which it lies past the stops [m/s]
STRUCTURE_N, FAST_M_S = 50.0, 0.1


@pytest.fixture(scope="module")
def case():
    sheet, data = truth_session(None)
    library = {c.effect: c for c in candidates(sheet, data[:2])}
    held = [make_record(d, held_out=True) for d in data[2:]]
    return sheet, library, held


def _fit(sheet, library, effect: str) -> StepFit:
    c = library[effect]
    values = {p.name: p.start for p in c.parameters}
    if effect == "end_stops":
        values.update(rebound_position_m=STOP_M, compression_position_m=-STOP_M)
    return StepFit(sheet, [c], {"effect": effect, "effects": [effect], "values": [values],
                                "std": [{}], "base_values": {}, "held": {}, "fit": {},
                                "seconds": 0.0, "evaluations": 0})


def _residuals(held, where: str) -> list[np.ndarray]:
    """1 N of white noise on each held-out file's counted samples, and 50 N of a slow
    structure (a sine of the sample index) ``where``: ``past`` the stops at speed, or
    ``everywhere``."""
    rng = np.random.default_rng(11)
    out = []
    for rec in held:
        x, v = rec.data.displacement[rec.start:], rec.data.velocity[rec.start:]
        n = x.size
        shape = STRUCTURE_N * math.sqrt(2.0) * np.sin(np.linspace(0.0, 8.0 * math.pi, n))
        past = (np.abs(x) > STOP_M) & (np.abs(v) > FAST_M_S)
        out.append(rng.normal(0.0, 1.0, n) + (np.where(past, shape, 0.0)
                                              if where == "past" else shape))
    return out


@pytest.mark.parametrize(("effect", "where", "settled"), [
    ("end_stops", "past", True),         # all that is left lies where the orifice is undetermined
    ("end_stops", "everywhere", False),  # structure where the files determine the stops too
    ("valve_lag", "past", False),        # no law left undetermined: every sample counts
])
def test_the_search_ends_where_what_is_left_lies_where_the_files_cannot_tell(
        case, effect, where, settled):
    sheet, library, held = case
    assert library["end_stops"].undetermined is not None  # the paper's programme
    f = _fit(sheet, library, effect)
    residuals = _residuals(held, where)
    f.residuals = lambda records: residuals
    rounds = LibraryRounds(SimpleNamespace(held=held), None, None, 4)
    whole = math.sqrt(np.mean(np.concatenate(residuals) ** 2))
    assert whole > 5.0 * SEARCH_NOISE_FACTOR  # far above 3× the noise over every sample
    assert rounds.settled(f) is settled
