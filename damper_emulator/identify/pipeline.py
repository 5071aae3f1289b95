"""Identification of a damper from a quasi-static and a chirp test (MODEL.md §3).

``identify`` alternates the two fits of the paper until they agree: the quasi-static fit
(eq 37) gives the gas spring and friction the chirp fit needs; the chirp fit gives the
valves, whose small viscous force at the quasi-static speed the quasi-static fit then
accounts for.  Geometry, ``γ``, ``ν`` and ``α`` come from a base parameter set (the data
sheet); the result is a complete, validated :class:`ModelConfig`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.identify.fitting import FitResult
from damper_emulator.identify.quasi_static import IdentificationError, fit_quasi_static
from damper_emulator.identify.valves import (MIN_SPEED_FRACTION, effective_variance_weights,
                                             fit_valve, hysteresis_filter, start_values)
from damper_emulator.model.gas import compression_chamber_pressure
from damper_emulator.model.incompressible import valve_pressure_drop
from damper_emulator.params import ModelConfig, ParameterError, ValveParams, validate

#: At most this many quasi-static ↔ chirp rounds.
MAX_ROUNDS = 6
#: Savitzky–Golay window of the pressure derivative in the compressibility correction.
PRESSURE_DERIVATIVE_WINDOW_S = 0.015
PRESSURE_DERIVATIVE_ORDER = 5
#: The alternation stops when no parameter moves by more than this fraction.
ROUND_TOLERANCE = 1e-4

Progress = Optional[Callable[[str], None]]


@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`."""

    config: ModelConfig
    quasi_static: FitResult
    rebound: FitResult
    compression: FitResult
    rounds: int
    #: chirp samples used by the valve fits, per direction
    chirp_samples: dict
    #: the flow, pressure drop and sample masks of the last round (arrays, for plots)
    series: dict = dataclasses.field(default_factory=dict, repr=False)

    def as_dict(self) -> dict:
        d = self.config.damper
        return {
            "damper": {
                "gas_pressure_static_pa": d.gas_pressure_static_pa,
                "gas_volume_static_m3": d.gas_volume_static_m3,
                "friction_force_n": d.friction_force_n,
                "rebound": dataclasses.asdict(d.rebound),
                "compression": dataclasses.asdict(d.compression),
            },
            "fixed": {k: getattr(d, k) for k in (
                "pressure_tube_length_m", "x0_m", "rod_diameter_m", "piston_diameter_m",
                "gas_gamma", "oil_kinematic_viscosity_m2_s", "oil_compressibility_per_pa")},
            "quasi_static_fit": self.quasi_static.as_dict(),
            "rebound_fit": self.rebound.as_dict(),
            "compression_fit": self.compression.as_dict(),
            "rounds": self.rounds,
            "chirp_samples": self.chirp_samples,
        }


def velocity_of(data: MeasuredData) -> np.ndarray:
    """The file's velocity column, or a Savitzky–Golay derivative of its displacement."""
    if data.velocity is not None:
        return data.velocity
    from damper_emulator.validation import estimate_velocity

    return estimate_velocity(data.time, data.displacement)[0]


def valve_flow_and_pressure_drop(t, x, v, force, damper, p_gas_pa, v_gas_m3, friction_n,
                                 correct_compressibility: bool = True):
    """Valve flow ``Q_pv`` [m³/s] and pressure drop ``p_reb − p_com`` [Pa] seen in the data.

    Eq 4 solved for the rebound-chamber pressure gives ``p_reb = (F − F_f sgn ẋ + A_pt
    P_com(x)) / (A_pt − A_rod)``.  Without correction the valve flow is the rigid-oil flow
    ``ẋ (A_pt − A_rod)`` (eqs 5–7, the paper's identification).  With it, eq 2 solved for
    the flow, ``Q_pv = ẋ (A_pt − A_rod) − ṗ_reb (L_pt − X0 − x)(A_pt − A_rod) α /
    (1 − α p_reb)``, removes the oil-compressibility lag that makes the force hysteretic;
    ``ṗ_reb`` is a Savitzky–Golay derivative (``PRESSURE_DERIVATIVE_ORDER``,
    ``PRESSURE_DERIVATIVE_WINDOW_S``).
    """
    a_ann, a_pt = damper.annulus_area_m2, damper.piston_area_m2
    alpha = damper.oil_compressibility_per_pa
    p_com = compression_chamber_pressure(x, p_gas_pa, v_gas_m3, damper.rod_area_m2,
                                         damper.gas_gamma)
    p_reb = (force - friction_n * np.sign(v) + a_pt * p_com) / a_ann
    q = v * a_ann
    # flow noise per newton of force noise: the derivative filter's noise gain × eq 2 factor
    flow_noise_per_n = np.zeros_like(q)
    if correct_compressibility:
        dt = float(np.median(np.diff(t)))
        # odd, and long enough for the polynomial order at any sample rate
        window = max(PRESSURE_DERIVATIVE_ORDER + 2,
                     int(round(PRESSURE_DERIVATIVE_WINDOW_S / dt))) | 1
        if window >= t.size:
            raise IdentificationError("the chirp is too short to differentiate the pressure")
        dpdt = savgol_filter(p_reb, window, PRESSURE_DERIVATIVE_ORDER, deriv=1, delta=dt,
                             mode="interp")
        factor = (damper.max_extension_m - x) * a_ann * alpha / (1.0 - alpha * p_reb)
        q = q - dpdt * factor
        gain = float(np.linalg.norm(savgol_coeffs(window, PRESSURE_DERIVATIVE_ORDER, deriv=1,
                                                  delta=dt)))
        flow_noise_per_n = gain * factor / a_ann
    return q, p_reb - p_com, flow_noise_per_n


def chirp_selection(t, v, q, dp, use_filter: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the chirp samples used for the rebound and compression fits: the paper's
    hysteresis filter (when ``use_filter``), speeds above ``MIN_SPEED_FRACTION`` of each
    direction's peak, and flow and pressure drop of the same sign."""
    keep = hysteresis_filter(v, np.gradient(v, t)) if use_filter else np.ones(v.size, bool)
    reb = keep & (v > MIN_SPEED_FRACTION * max(v.max(), 0.0)) & (q > 0) & (dp > 0)
    com = keep & (v < MIN_SPEED_FRACTION * min(v.min(), 0.0)) & (q < 0) & (dp < 0)
    return reb, com


def identify(quasi_static: MeasuredData, chirp: MeasuredData, base: ModelConfig,
             progress: Progress = None, correct_compressibility: bool = True,
             hysteresis_filter_on: bool = True,
             start_factors: Optional[dict] = None) -> Identification:
    """Identify gas spring, friction and both valves (see the module docstring).

    ``start_factors`` (``{"rebound": [5 factors], "compression": [...]}``) scales the
    data-derived valve start values, to check that the optimum does not depend on them.

    Raises
    ------
    IdentificationError
        Data that cannot support the fit, or a fitted valve that is not invertible.
    """
    say = progress or (lambda msg: None)
    d = base.damper
    a_rod, a_ann, gamma = d.rod_area_m2, d.annulus_area_m2, d.gas_gamma
    nu, form = d.oil_kinematic_viscosity_m2_s, base.numerics.valve_form
    xq, vq, fq = quasi_static.displacement, velocity_of(quasi_static), quasi_static.force
    tc, xc, vc, fc = chirp.time, chirp.displacement, velocity_of(chirp), chirp.force
    cfg = base
    fits: dict[str, FitResult] = {}
    previous = None
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):
        valve_force = (None if not fits else
                       valve_pressure_drop(vq, cfg) * a_ann)
        qs = fit_quasi_static(xq, vq, fq, a_rod, gamma, valve_force)
        p_gas, v_gas, friction = qs.values
        say(f"round {rounds}: quasi-static P_gas {p_gas / 1e6:.4f} MPa, V_gas "
            f"{v_gas * 1e6:.2f} cm³, friction {friction:.1f} N (r.m.s. {qs.rms:.2f} N)")
        q_all, dp_all, q_noise = valve_flow_and_pressure_drop(
            tc, xc, vc, fc, d, p_gas, v_gas, friction, correct_compressibility)
        force_sd = qs.rms  # the quasi-static residual: the force measurement's noise
        masks = dict(zip(("rebound", "compression"),
                         chirp_selection(tc, vc, q_all, dp_all, hysteresis_filter_on)))
        for side, m in masks.items():
            if m.sum() < 20:
                raise IdentificationError(
                    f"{chirp.name or 'chirp'}: only {int(m.sum())} {side} samples are usable "
                    "for the valve fit (need 20)")
        for side in ("rebound", "compression"):
            m = masks[side]
            qa = np.abs(q_all[m])
            if side in fits:
                start = fits[side].values
            else:
                start = start_values(qa, np.abs(dp_all[m]), nu)
                if start_factors is not None:
                    start = start * np.asarray(start_factors[side], float)
            weights = None
            if correct_compressibility and start is not None:
                weights = effective_variance_weights(qa, force_sd * q_noise[m], force_sd,
                                                     a_ann, start, nu, form)
            fits[side] = fit_valve(qa, np.abs(dp_all[m]), a_ann, nu, form, start, weights)
            say(f"round {rounds}: {side} valve r.m.s. {fits[side].rms:.2f} N "
                f"({fits[side].samples} samples)")
        current = np.concatenate((qs.values, fits["rebound"].values,
                                  fits["compression"].values))
        try:
            cfg = dataclasses.replace(base, damper=dataclasses.replace(
                d, gas_pressure_static_pa=float(p_gas), gas_volume_static_m3=float(v_gas),
                friction_force_n=float(friction),
                rebound=ValveParams(*map(float, fits["rebound"].values)),
                compression=ValveParams(*map(float, fits["compression"].values))))
            validate(cfg)
        except ParameterError as exc:
            raise IdentificationError(f"the fitted parameters are not a valid damper: {exc}")
        if previous is not None and np.all(np.abs(current / previous - 1) < ROUND_TOLERANCE):
            break
        previous = current
    series = {"flow_m3_s": q_all, "pressure_drop_pa": dp_all, "masks": masks,
              "quasi_static_valve_force_n": valve_force}
    return Identification(cfg, qs, fits["rebound"], fits["compression"], rounds,
                          {k: int(m.sum()) for k, m in masks.items()}, series)
