"""A virtual production batch to try ``fleet`` on (``damper-hil fleet-example``).

Every unit is the nominal damper (``--params``, default ``config/sport.yaml``) with its own
unit-to-unit scatter (:class:`Scatter`: normal, relative, per unit and per valve
direction), run over the dyno protocol of the diagnosis's truth simulation
(:mod:`damper_emulator.diagnose.truth`: quasi-static, chirp and the validation sines, 4 N
of force noise, smooth friction and displacement noise, a model-form difference from the
emulator's model, as real data have).  A few units carry a defect a production line
looks for (:data:`DEFECTS`), on fixed unit numbers, so that the outcome is known:
``DATA_DIR/truth.json`` lists every unit's true parameters and defect (it is not in any
damper's folder, and ``fleet`` does not read it).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.diagnose.truth import (
    REALISTIC,
    Protocol,
    simulate_session,
    with_extensions,
    write_session,
)
from damper_emulator.dyno import protocols
from damper_emulator.outputs import write_text
from damper_emulator.params import ModelConfig, rule, save_config

#: the force noise of the example's dyno [N] (the diagnosis benchmark's)
NOISE_N = 4.0
#: the short protocol of ``--short`` (the diagnosis tests'): a 12 s chirp, one
#: quasi-static cycle
SHORT = Protocol(chirp=protocols.Chirp(duration_s=12.0),
                 quasi_static=protocols.QuasiStatic(cycles=1))


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
    3: ("low_gas_charge", lambda c: _damper(c, gas_pressure_static_pa=0.6
                                            * c.damper.gas_pressure_static_pa)),
    5: ("high_friction", lambda c: _damper(c, friction_force_n=2.5
                                           * c.damper.friction_force_n)),
    8: ("valve_lag", lambda c: with_extensions(c, {"valve_lag": {"time_constant_s": 4e-3}})),
}


def _damper(cfg: ModelConfig, **changes: Any) -> ModelConfig:
    return dataclasses.replace(cfg, damper=dataclasses.replace(cfg.damper, **changes))


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
    return _damper(nominal, gas_pressure_static_pa=draw(d.gas_pressure_static_pa,
                                                        scatter.gas_pressure),
                   gas_volume_static_m3=draw(d.gas_volume_static_m3, scatter.gas_volume),
                   friction_force_n=draw(d.friction_force_n, scatter.friction), **valves)


def write_example(out: Path, nominal: ModelConfig, count: int, seed: int = 0,
                  short: bool = False, scatter: Scatter = Scatter(),
                  say: Callable[[str], None] = print) -> dict[str, Any]:
    """Write ``count`` units' test sets into ``out/unit_NN/`` and ``out/truth.json``;
    returns the truth document."""
    rng = np.random.default_rng(seed)
    protocol = SHORT if short else Protocol()
    out.mkdir(parents=True, exist_ok=True)
    width = max(2, len(str(count)))
    units = {}
    for k in range(1, count + 1):
        uid = f"unit_{k:0{width}d}"
        cfg = unit_config(nominal, scatter, rng)
        defect = None
        if k in DEFECTS:
            defect, change = DEFECTS[k]
            cfg = change(cfg)
        folder = out / uid
        write_session(simulate_session(cfg, protocol, NOISE_N, seed=seed * 100_003 + k,
                                       form=REALISTIC), folder)
        save_config(_damper(nominal, extensions=None), folder / "base.yaml")
        d = cfg.damper
        units[uid] = {"defect": defect,
                      "gas_pressure_static_pa": d.gas_pressure_static_pa,
                      "gas_volume_static_m3": d.gas_volume_static_m3,
                      "friction_force_n": d.friction_force_n,
                      "rebound": dataclasses.asdict(d.rebound),
                      "compression": dataclasses.asdict(d.compression),
                      "extensions": (dataclasses.asdict(d.extensions)
                                     if d.extensions is not None else None)}
        say(f"[{k}/{count}] {uid}" + (f" (defect: {defect})" if defect else ""))
    doc = {"count": count, "seed": seed, "protocol": "short" if short else "paper",
           "noise_n": NOISE_N, "scatter": dataclasses.asdict(scatter), "units": units}
    write_text(out / "truth.json", json.dumps(doc, indent=2) + "\n")
    return doc
