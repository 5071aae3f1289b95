"""What the tests of the lab-data readers (test_column_map, test_tdms, test_mdf) share:
the paper's identification tests on the model, and the check that data read from a lab's
file identify as the record they came from."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from damper_emulator.dyno import protocols
from damper_emulator.identify.pipeline import identify
from damper_emulator.model.compressible import simulate

#: an ulp of converted data moves the valve fit's leak constant along a flat direction of
#: its cost by 4e-9 to 1.3e-8 (measured); a unit wrong by a percent moves it far more
IDENTIFICATION_RTOL = 1e-7


def protocol_records(model, seed: int) -> Iterator[tuple[str, np.ndarray, ...]]:
    """``(name, t, x, force, temperature)`` of the quasi-static test and a 20 s chirp on
    ``model``, with 4 N of force noise."""
    rng = np.random.default_rng(seed)
    for name, (t, x, v) in (("qs", protocols.quasi_static()),
                            ("chirp", protocols.chirp(duration_s=20.0))):
        force = simulate(model, t, x, v).force_n + rng.normal(0, 4.0, t.size)
        yield name, t, x, force, np.full(t.size, 25.0)


def assert_same_identification(reference: list, read: list, cfg) -> None:
    """``identify`` on ``read`` (the records through a lab file) gives ``reference``'s
    parameters (each list: the quasi-static test, the chirp)."""
    a = identify([reference[0]], [reference[1]], cfg).config.damper
    b = identify([read[0]], [read[1]], cfg).config.damper
    for side in ("rebound", "compression"):
        np.testing.assert_allclose(tuple(getattr(b, side)), tuple(getattr(a, side)),
                                   rtol=IDENTIFICATION_RTOL, err_msg=side)
    for key in ("gas_pressure_static_pa", "gas_volume_static_m3", "friction_force_n"):
        np.testing.assert_allclose(getattr(b, key), getattr(a, key),
                                   rtol=IDENTIFICATION_RTOL, err_msg=key)


