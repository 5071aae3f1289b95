"""A virtual production batch to try ``fleet`` on (``damper-hil fleet-example``).

Every unit is the nominal damper (``--params``, default ``config/sport.yaml``) with its own
unit-to-unit scatter (:class:`~damper_hil.fleet.scatter.Scatter`: normal, relative, per
unit and per valve direction), run over the dyno protocol of the diagnosis's truth simulation
(:mod:`damper_emulator.diagnose.truth`: quasi-static, chirp and the validation sines, 4 N
of force noise, smooth friction and displacement noise, a model-form difference from the
emulator's model, as real data have).  A few units carry a defect a production line
looks for (:data:`~damper_hil.fleet.scatter.DEFECTS`), on fixed unit numbers, so that the
outcome is known:
``DATA_DIR/truth.json`` lists every unit's true parameters and defect (it is not in any
damper's folder, and ``fleet`` does not read it).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.diagnose.truth import REALISTIC, Protocol, simulate_session, write_session
from damper_emulator.dyno import protocols
from damper_emulator.outputs import write_text
from damper_emulator.params import ModelConfig, save_config
from damper_hil.fleet.scatter import DEFECTS, Scatter, unit_config

#: the force noise of the example's dyno [N] (the diagnosis benchmark's)
NOISE_N = 4.0
#: the short protocol of ``--short`` (the diagnosis tests'): a 12 s chirp, one
#: quasi-static cycle
SHORT = Protocol(chirp=protocols.Chirp(duration_s=12.0),
                 quasi_static=protocols.QuasiStatic(cycles=1))


def write_example(out: Path, nominal: ModelConfig, count: int, seed: int = 0,
                  short: bool = False, scatter: Scatter | None = None,
                  say: Callable[[str], None] = print) -> dict[str, Any]:
    """Write ``count`` units' test sets into ``out/unit_NN/`` and ``out/truth.json``;
    returns the truth document (``scatter``: :class:`Scatter`'s defaults when ``None``)."""
    scatter = Scatter() if scatter is None else scatter
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
        save_config(nominal.replace_damper(extensions=None), folder / "base.yaml")
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
