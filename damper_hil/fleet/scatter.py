"""The unit-to-unit scatter and the seeded defects of a virtual production batch
(``damper-hil fleet-example``, :mod:`.example`).

Kept apart from :mod:`.example`, which simulates the batch's dyno tests: the command
line builds its options from :class:`Scatter` and its help from :data:`DEFECTS` on every
start, and this module imports no more than the parameter schema.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from damper_emulator.params import ModelConfig, with_extensions
from damper_emulator.schema import rule


@dataclass(frozen=True)
class Scatter:
    """Unit-to-unit scatter of a production batch: one standard deviation, relative."""

    gas_pressure: float = rule(("closed", 0.0, 0.3),
                               "gas charge pressure scatter, 1 sigma [-]", 0.02)
    gas_volume: float = rule(("closed", 0.0, 0.3), "gas volume scatter, 1 sigma [-]", 0.02)
    friction: float = rule(("closed", 0.0, 0.5), "seal friction scatter, 1 sigma [-]", 0.08)
    valve: float = rule(("closed", 0.0, 0.3),
                        "scatter of each valve constant (leak, port, spring, preload), "
                        "per direction, 1 sigma [-]", 0.04)


#: seeded defects: unit number (1-based; only if the batch is that large) →
#: (name, the change).  A leaking gas chamber, a tight seal, a valve whose shims react
#: late (a lag, found by ``--diagnose``).
DEFECTS: dict[int, tuple[str, Callable[[ModelConfig], ModelConfig]]] = {
    3: ("low_gas_charge", lambda c: c.replace_damper(
        gas_pressure_static_pa=0.6 * c.damper.gas_pressure_static_pa)),
    5: ("high_friction", lambda c: c.replace_damper(
        friction_force_n=2.5 * c.damper.friction_force_n)),
    8: ("valve_lag", lambda c: with_extensions(c, {"valve_lag": {"time_constant_s": 4e-3}})),
}


def unit_config(nominal: ModelConfig, scatter: Scatter, rng: np.random.Generator
                ) -> ModelConfig:
    """One unit of the batch: ``nominal`` with its scatter drawn from ``rng``."""
    d = nominal.damper

    def draw(value: float, sigma: float) -> float:
        # a normal scatter, truncated at 3 sigma (a production line scraps the rest)
        return float(value * (1.0 + sigma * np.clip(rng.standard_normal(), -3.0, 3.0)))

    valves = {side: dataclasses.replace(
        getattr(d, side), **{k: draw(getattr(getattr(d, side), k), scatter.valve)
                             for k in ("k_leak", "k_port", "k_spring", "preload_pa")})
        for side in ("rebound", "compression")}
    return nominal.replace_damper(
        gas_pressure_static_pa=draw(d.gas_pressure_static_pa, scatter.gas_pressure),
        gas_volume_static_m3=draw(d.gas_volume_static_m3, scatter.gas_volume),
        friction_force_n=draw(d.friction_force_n, scatter.friction), **valves)
