"""Continuous semi-active skyhook control of the adaptive damper (docs/model.md §6).

Which velocities
----------------
- ``body_velocity_m_s`` ``v_b``: the sprung mass's **absolute** vertical velocity [m/s, up +]
  (the quarter car's ``z2'``), not referred through the motion ratio;
- ``damper_velocity_m_s`` ``v_d``: the damper's stroke rate [m/s, **extension +**, i.e. the
  body moving away from the wheel]: the quarter car's suspension rate over the motion
  ratio, ``v_d = (z2' − z1') / MR`` (:mod:`ride_sim.quarter_car`).

The law works on the **damper side**: the demanded damper force (rebound +) is
``F* = c_sky v_b``.  On the body the damper force acts as ``F/MR`` (opposing extension), so
``c_sky`` is ``MR ×`` the skyhook damping ``c_body`` the body feels: ``F*/MR = c_body v_b``
pulls the body down while it rises.

Law
---
A passive damper can only push against its own motion (``F`` has the sign of ``v_d``), so
``F*`` is achievable only when ``v_b v_d > 0``; otherwise the softest setting is asked for::

    v_b v_d > 0:   c_req = F*/v_d = c_sky |v_b| / max(|v_d|, deadband)
                   c = clip((c_req − c_soft) / (c_firm − c_soft), 0, 1)
    otherwise:     c = 0 (comfort)

``c_soft``, ``c_firm`` are equivalent linear damping rates [N s/m, damper side] of the
comfort (command 0) and sport (command 1) settings, taken **per direction** (rebound for
``v_d > 0``, compression for ``v_d < 0``: the sport damper is about 3× firmer in rebound).
By default (``rates_from: model``) they are computed from the damper model,
``(F_qs(±v_ref) − F_static)/(±v_ref)`` with the quasi-steady force
(:func:`damper_emulator.model.compressible.quasi_steady_force`, friction included) at
``reference_velocity_m_s``; with ``rates_from: config`` they are the four ``c_*_ns_m`` of
``config/skyhook.yaml``.  The deadband keeps the division away from ``v_d ≈ 0``: there the
required rate is large and the law asks for the firmest setting, as the ideal skyhook does.

The command is recomputed at ``rate_hz`` and held in between (zero-order hold); the
damper's solenoid lag (``damper.adaptive.solenoid_t63_s``) acts on it in the model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from damper_emulator.errors import UserError
from damper_emulator.schema import (
    ParameterError,
    build_group,
    check_value,
    node_parameters,
    read_yaml,
    rule,
)

#: Default parameter file.
DEFAULT_SKYHOOK_FILE = Path(__file__).resolve().parent.parent / "config" / "skyhook.yaml"
#: Where ``c_soft`` / ``c_firm`` come from.
RATE_SOURCES = ("model", "config")


@dataclass(frozen=True)
class SkyhookParams:
    """The ``skyhook`` group of ``config/skyhook.yaml`` (see the module docstring)."""

    c_sky_ns_m: float = rule("positive", "demanded damper force per body velocity [N s/m] "
                                         "(MR x the skyhook damping on the body)")
    rate_hz: float = rule(("range", 0.0, 100000.0), "controller update rate [Hz]; the "
                                                    "command is held in between", 200.0)
    deadband_m_s: float = rule("positive", "|damper velocity| below this counts as this in "
                                           "the required rate [m/s]", 0.01)
    rates_from: str = rule(("choices", RATE_SOURCES),
                           "model: comfort/sport rates from the damper at "
                           "reference_velocity_m_s; config: the c_*_ns_m values", "model")
    reference_velocity_m_s: float = rule("positive", "damper velocity of the equivalent "
                                                     "linear rates (rates_from: model) [m/s]",
                                         0.2)
    c_soft_rebound_ns_m: float = rule("positive", "comfort rate in rebound, damper side "
                                                  "[N s/m] (rates_from: config)", 1555.0)
    c_firm_rebound_ns_m: float = rule("positive", "sport rate in rebound, damper side "
                                                  "[N s/m] (rates_from: config)", 13132.0)
    c_soft_compression_ns_m: float = rule("positive", "comfort rate in compression, damper "
                                                      "side [N s/m] (rates_from: config)",
                                          1503.0)
    c_firm_compression_ns_m: float = rule("positive", "sport rate in compression, damper "
                                                      "side [N s/m] (rates_from: config)",
                                          4360.0)


class SkyhookRates(NamedTuple):
    """Equivalent linear rates [N s/m, damper side] of comfort (soft) and sport (firm)."""

    soft_rebound: float
    firm_rebound: float
    soft_compression: float
    firm_compression: float


def check_rates(rates: SkyhookRates, where: str = "skyhook rates") -> SkyhookRates:
    """``rates`` if every rate is positive and finite and firm > soft in each direction;
    else :class:`ParameterError` (one line)."""
    for name, value in rates._asdict().items():
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{where}: {name} = {value:g} N s/m must be positive")
    for side in ("rebound", "compression"):
        soft, firm = getattr(rates, f"soft_{side}"), getattr(rates, f"firm_{side}")
        if not firm > soft:
            raise ParameterError(
                f"{where}: the firm {side} rate {firm:g} N s/m must exceed the soft one "
                f"{soft:g} N s/m (a damper without a bypass cannot be controlled)")
    return rates


def equivalent_rates(model, reference_velocity_m_s: float) -> SkyhookRates:
    """Comfort and sport rates of a ``DamperModel`` at ``±reference_velocity_m_s``:
    ``(F_qs(±v) − F_static)/(±v)`` from the quasi-steady force (rigid-oil equilibrium,
    friction included) at commands 0 and 1."""
    from damper_emulator.model.compressible import quasi_steady_force

    v = float(reference_velocity_m_s)
    if not (math.isfinite(v) and v > 0):
        raise UserError(f"reference velocity must be positive, got {reference_velocity_m_s!r}")
    f0 = quasi_steady_force(model, 0.0)

    def rate(velocity: float, command: float) -> float:
        return (quasi_steady_force(model, velocity, command) - f0) / velocity

    return SkyhookRates(rate(v, 0.0), rate(v, 1.0), rate(-v, 0.0), rate(-v, 1.0))


def _config_rates(params: SkyhookParams) -> SkyhookRates:
    return SkyhookRates(params.c_soft_rebound_ns_m, params.c_firm_rebound_ns_m,
                        params.c_soft_compression_ns_m, params.c_firm_compression_ns_m)


def resolve_rates(params: SkyhookParams, model=None) -> SkyhookRates:
    """The rates the law uses: from ``model`` (``rates_from: model``; default the sport
    damper of ``config/sport.yaml``) or from ``params`` (``rates_from: config``), checked
    (:func:`check_rates`)."""
    if params.rates_from == "config":
        return check_rates(_config_rates(params), "skyhook (rates_from: config)")
    if model is None:
        from damper_emulator.model.compressible import DamperModel
        model = DamperModel()
    return check_rates(equivalent_rates(model, params.reference_velocity_m_s),
                       f"skyhook rates of damper '{model.cfg.damper.name}' at "
                       f"{params.reference_velocity_m_s:g} m/s")


def skyhook_command(body_velocity_m_s, damper_velocity_m_s, c_sky_ns_m: float,
                    rates: SkyhookRates, deadband_m_s: float):
    """Valve command (0 comfort .. 1 sport) of the continuous skyhook law.

    Parameters
    ----------
    body_velocity_m_s : float or array_like
        Sprung-mass absolute vertical velocity ``v_b`` [m/s, up +].
    damper_velocity_m_s : float or array_like
        Damper stroke rate ``v_d`` [m/s, extension +] (suspension rate / motion ratio).
    c_sky_ns_m : float
        Demanded damper force per body velocity [N s/m]: ``F* = c_sky v_b``.
    rates : SkyhookRates
        Comfort and sport equivalent rates per direction, damper side.
    deadband_m_s : float
        ``|v_d|`` below this counts as this in ``F*/v_d`` (> 0).

    Returns
    -------
    float or ndarray
        ``clip((c_sky |v_b| / max(|v_d|, deadband) − c_soft)/(c_firm − c_soft), 0, 1)`` where
        ``v_b v_d > 0``, else 0; ``c_soft``, ``c_firm`` those of the direction of ``v_d``.
    """
    vb = np.asarray(body_velocity_m_s, dtype=float)
    vd = np.asarray(damper_velocity_m_s, dtype=float)
    rebound = vd > 0.0
    soft = np.where(rebound, rates.soft_rebound, rates.soft_compression)
    firm = np.where(rebound, rates.firm_rebound, rates.firm_compression)
    required = c_sky_ns_m * np.abs(vb) / np.maximum(np.abs(vd), deadband_m_s)
    command = np.clip((required - soft) / (firm - soft), 0.0, 1.0)
    command = np.where(vb * vd > 0.0, command, 0.0)
    return float(command) if command.ndim == 0 else command


def skyhook_from_mapping(doc: Any, source: str = "<memory>") -> SkyhookParams:
    """Build and validate :class:`SkyhookParams` from a parsed params file (group
    ``skyhook``, in ``<node>: ros__parameters:`` or bare)."""
    body = node_parameters(doc, source, "skyhook")
    return build_group(SkyhookParams, body["skyhook"] if body["skyhook"] is not None else {},
                       "skyhook", source, check_value)


def load_skyhook(path: str | Path | None = None) -> SkyhookParams:
    """Load and validate a skyhook params file (default ``config/skyhook.yaml``); a bad
    file raises :class:`~damper_emulator.schema.ParameterError` (one line naming the file
    and the key)."""
    path = Path(path) if path is not None else DEFAULT_SKYHOOK_FILE
    params = skyhook_from_mapping(read_yaml(path), str(path))
    if params.rates_from == "config":       # firm > soft, checked at load
        check_rates(_config_rates(params), f"{path}: skyhook")
    return params
