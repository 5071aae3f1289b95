"""What the tests of the lab-data readers (test_column_map, test_tdms, test_mdf) share:
the paper's identification tests on the model, and the check that data read from a lab's
file identify as the record they came from."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from damper_emulator.dyno import protocols
from damper_emulator.identify.pipeline import identify
from damper_emulator.model.compressible import DamperModel, simulate

#: an ulp of converted data moves the valve fit's leak constant along a flat direction of
#: its cost by 4e-9 to 1.3e-8 (measured: the optimum itself moves, the fit's tolerances are
#: 1e-12); a unit wrong by a percent moves it far more
IDENTIFICATION_RTOL = 1e-7
#: the identified dampers' forces on the tests agree far closer, the flat direction being
#: one that the force does not see: to this share of the largest force (1.5e-10 measured,
#: 8e-7 N of 5 kN)
FORCE_RTOL = 1e-9


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
    damper (each list: the quasi-static test, the chirp): its forces on the tests to
    :data:`FORCE_RTOL` of the largest, its parameters to :data:`IDENTIFICATION_RTOL`."""
    fitted = [identify([r[0]], [r[1]], cfg).config for r in (reference, read)]
    forces = [[simulate(DamperModel(c), d.time, d.displacement, d.velocity_or_derivative()
                        ).force_n for d in reference] for c in fitted]
    scale = max(float(np.abs(f).max()) for f in forces[0])
    for fa, fb in zip(*forces):
        np.testing.assert_allclose(fb, fa, rtol=0, atol=FORCE_RTOL * scale)
    a, b = (c.damper for c in fitted)
    for side in ("rebound", "compression"):
        np.testing.assert_allclose(tuple(getattr(b, side)), tuple(getattr(a, side)),
                                   rtol=IDENTIFICATION_RTOL, err_msg=side)
    for key in ("gas_pressure_static_pa", "gas_volume_static_m3", "friction_force_n"):
        np.testing.assert_allclose(getattr(b, key), getattr(a, key),
                                   rtol=IDENTIFICATION_RTOL, err_msg=key)


