"""Identification of a damper from a quasi-static and a chirp test (docs/model.md §3).

``identify`` alternates the two fits of the paper until they agree: the quasi-static fit
(eq 37) gives the gas spring and friction the chirp fit needs; the chirp fit gives the
valves, whose small viscous force at the quasi-static speed the quasi-static fit then
accounts for.  Geometry, ``γ``, ``ν`` and ``α`` come from a base parameter set (the data
sheet); the result is a complete, validated :class:`ModelConfig`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.signal import savgol_coeffs, savgol_filter

from damper_emulator.acquisition.chain import delayed, relative_delay, unscaled
from damper_emulator.blas import one_blas_thread
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.identify.fitting import FitResult
from damper_emulator.identify.quasi_static import IdentificationError, fit_quasi_static
from damper_emulator.identify.valves import (
    MIN_SPEED_FRACTION,
    effective_variance_weights,
    fit_valve,
    hysteresis_filter,
    start_values,
)
from damper_emulator.model.compressible import DamperModel, simulate
from damper_emulator.model.gas import compression_chamber_pressure
from damper_emulator.model.incompressible import valve_pressure_drop
from damper_emulator.params import ModelConfig, ValveParams, validate
from damper_emulator.schema import ParameterError

#: At most this many quasi-static ↔ chirp rounds.
MAX_ROUNDS = 6
#: Savitzky–Golay window of the pressure derivative in the compressibility correction.
PRESSURE_DERIVATIVE_WINDOW_S = 0.015
PRESSURE_DERIVATIVE_ORDER = 5
#: The alternation stops when no parameter moves by more than this fraction.
ROUND_TOLERANCE = 1e-4

#: Default α search range of ``identify(fit_alpha=True)``: these factors × the base α.
ALPHA_BOUND_FACTORS = (0.1, 100.0)
#: The α search stops when log α is known to this (about 5 % in α).
ALPHA_LOG_TOLERANCE = 0.05
#: Score of an α whose identification fails (larger than any force error of interest) [N].
ALPHA_FAILED_SCORE = 1e12
#: Time between joined files [s]: longer than the model's settle gap, so the compressible
#: simulation restarts from equilibrium at the start of every file.
JOIN_GAP_S = 1.0
#: The valve fit of one direction uses at most this many chirp samples.  Its cost grows
#: with the samples (every residual evaluation runs the valve characteristic and its
#: complex-step Jacobian at each), and a long or fast chirp adds nothing but samples: a
#: 250 s chirp at 20 kHz selects 1.1 million per direction and took 14–61 s per fit.  The
#: paper's protocol (60 s at 1 kHz) selects about 13,400 per direction and is fitted whole;
#: a capped fit's standard errors are about √(13,400 / 50,000) ≈ 0.5 × the paper
#: protocol's (the same noise and flow range assumed).  See :func:`thin_selection`.
MAX_VALVE_FIT_SAMPLES = 50_000

Progress = Callable[[str], None] | None
Tests = MeasuredData | Sequence[MeasuredData]


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
    #: the α search of :func:`identify` with ``fit_alpha`` (``None`` when α was fixed)
    alpha_fit: dict | None = None
    #: chirp samples usable by the valve fits, per direction, before
    #: :func:`thin_selection` (``chirp_samples`` when nothing was dropped)
    chirp_samples_usable: dict = dataclasses.field(default_factory=dict)
    #: the configuration's friction (the valve fits') over the quasi-static fit's
    chirp_friction_factor: float = 1.0

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
            "chirp_samples_usable": self.chirp_samples_usable,
            "alpha_fit": self.alpha_fit,
            "chirp_friction_factor": self.chirp_friction_factor,
        }


def velocity_of(data: MeasuredData) -> np.ndarray:
    """The file's velocity column, or a Savitzky–Golay derivative of its displacement."""
    if data.velocity is not None:
        return data.velocity
    from damper_emulator.validation import estimate_velocity

    return estimate_velocity(data.time, data.displacement)[0]


def join_tests(tests: Tests, gap_s: float = JOIN_GAP_S) -> tuple[MeasuredData, list[slice]]:
    """Join one or more test files into one record on a continuous time axis.

    Each file keeps its own velocity (its column, or the derivative of its own
    displacement); file ``k + 1`` starts ``gap_s`` after the end of file ``k``.  Returns
    the joined record and the slice of every file in it.
    """
    files = [tests] if isinstance(tests, MeasuredData) else list(tests)
    if not files:
        raise IdentificationError("no test file given")
    if len(files) == 1:
        one = files[0]
        joined = dataclasses.replace(one, velocity=velocity_of(one))
        return joined, [slice(0, len(one))]
    times, slices, start, offset = [], [], 0, 0.0
    for data in files:
        times.append(data.time - data.time[0] + offset)
        offset = times[-1][-1] + gap_s
        slices.append(slice(start, start + len(data)))
        start += len(data)

    def cat(name):
        parts = [getattr(d, name) for d in files]
        return None if any(p is None for p in parts) else np.concatenate(parts)

    joined = MeasuredData(np.concatenate(times), cat("displacement"), cat("force"),
                          np.concatenate([velocity_of(d) for d in files]), cat("temperature"),
                          name=" + ".join(d.name or "?" for d in files),
                          path=" + ".join(d.path for d in files))
    return joined, slices


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


def thin_selection(mask: np.ndarray, max_samples: int = MAX_VALVE_FIT_SAMPLES
                   ) -> tuple[np.ndarray, int]:
    """Every ``k``-th selected sample, in time order, with the smallest ``k`` that leaves at
    most ``max_samples``.

    Used after the valve flow, its compressibility correction (the pressure derivative,
    which needs the full sample rate) and the hysteresis filter were worked out on every
    sample.  The valve fit is of a static characteristic ``Δp(Q)``: what it needs from the
    samples is their spread over the flow range, which a uniform stride through the
    selected samples of the whole chirp keeps; the samples are points, not block averages,
    so the non-linear ``Δp(Q)`` is not biased by averaging.  The force noise of the
    dropped samples is not averaged in: the standard errors grow by about ``√k`` against
    a fit of every sample.

    Parameters
    ----------
    mask : ndarray of bool
        The selected samples.
    max_samples : int
        At most this many stay selected.

    Returns
    -------
    thinned : ndarray of bool
        ``mask`` itself when it selects no more than ``max_samples``, else a new mask.
    stride : int
        ``k`` (1 when nothing was dropped).
    """
    selected = np.flatnonzero(mask)
    if selected.size <= max_samples:
        return mask, 1
    stride = -(-selected.size // max_samples)  # ceiling division
    thinned = np.zeros_like(mask)
    thinned[selected[::stride]] = True
    return thinned, stride


def aligned(data: MeasuredData) -> MeasuredData:
    """``data`` with its force moved earlier by its measurement chain's delay of the force
    against the displacement (:func:`damper_emulator.acquisition.chain.relative_delay`;
    a 2nd-order Butterworth load-cell filter at 200 Hz: 1.1 ms, 5° of phase at 12 Hz) and
    its force channel's gain and zero taken out, the pairs of force and motion the staged
    fits take; ``data`` itself without a chain."""
    rig = data.acquisition
    if rig is None or rig.does_nothing:
        return data
    tau = relative_delay(rig)
    force = unscaled(data.time, data.force, rig.force)  # the channel's gain and zero
    return dataclasses.replace(data, force=delayed(data.time, force, -tau))


def aligned_tests(tests: Tests) -> Tests:
    """:func:`aligned` of one test or of each of several."""
    if isinstance(tests, MeasuredData):
        return aligned(tests)
    return [aligned(d) for d in tests]


def chirp_simulation_rms(cfg: ModelConfig, chirp: MeasuredData) -> float:
    """r.m.s. force error [N] of the compressible model over the whole (joined) chirp."""
    res = simulate(DamperModel(cfg), chirp.time, chirp.displacement, chirp.velocity)
    return float(np.sqrt(np.mean((res.force_n - chirp.force) ** 2)))


@one_blas_thread
def identify(quasi_static: Tests, chirp: Tests, base: ModelConfig,
             progress: Progress = None, correct_compressibility: bool = True,
             hysteresis_filter_on: bool = True,
             start_factors: dict | None = None,
             fixed: Mapping[str, Mapping[str, float]] | None = None,
             fit_alpha: bool = False,
             alpha_bounds_per_pa: tuple[float, float] | None = None,
             exclude: tuple[np.ndarray | None, np.ndarray | None] | None = None,
             max_valve_samples: int = MAX_VALVE_FIT_SAMPLES,
             chirp_friction_factor: float = 1.0) -> Identification:
    """Identify gas spring, friction and both valves (see the module docstring).

    ``exclude`` = ``(quasi-static mask, chirp mask)`` (either ``None``): samples of the
    joined quasi-static and chirp records that no fit uses, e.g. where an effect the
    paper's model lacks is known to act (``diagnose`` leaves out the samples where a
    cavity is open or an end stop engaged).  ``max_valve_samples``: the valve fit of one
    direction takes at most this many chirp samples (:func:`thin_selection`).
    ``chirp_friction_factor``: the friction at the chirp's speeds, which the valve fits
    take out of the measured force (eq 4) and the configuration gets, is this multiple of
    the quasi-static fit's (1: the paper's method, one friction).  A seal's friction is not
    the same at a few mm/s as at 1 m/s; the valves take up the difference (both
    directions' pressure drops move by it), which ``diagnose`` searches where an effect's
    force trades with the friction (:mod:`damper_emulator.diagnose.joint`).

    With ``fit_alpha`` the oil compressibility α (eq 1) is fitted too, as the paper
    suggests ("adjusted slightly to absorb other compliances"): a bounded scalar search on
    ``log α`` (``alpha_bounds_per_pa``, default ``ALPHA_BOUND_FACTORS`` × the base α)
    minimising the compressible model's r.m.s. force error over the whole chirp, each α
    with its own complete identification (the valve flow's compressibility correction
    depends on α).  The search is recorded in :attr:`Identification.alpha_fit`.

    ``quasi_static`` and ``chirp`` are one test file each or several (joined with
    :func:`join_tests`; the valve flow and the hysteresis filter are worked out file by
    file).  ``start_factors`` (``{"rebound": [5 factors], "compression": [...]}``) scales
    the data-derived valve start values, to check that the optimum does not depend on them.
    ``fixed`` (``{"rebound": {"smoothing_g": 1.5}, "compression": {...}}``) holds valve
    parameters at given values where the data cannot determine them.

    Records that carry their rig's measurement chain (``MeasuredData.acquisition``) are
    fitted with their force moved earlier by the chain's delay of the force against the
    displacement (:func:`aligned`): the staged fits compare samples, not simulations.

    It runs its BLAS on one thread (:func:`~damper_emulator.blas.one_blas_thread`), the
    caller's threads given back after: threaded BLAS splits sums by thread, and the
    identified model's last bits, which a diagnosis's fits can follow, would otherwise
    depend on the machine's core count.

    Raises
    ------
    IdentificationError
        Data that cannot support the fit, or a fitted valve that is not invertible.
    """
    quasi_static, chirp = aligned_tests(quasi_static), aligned_tests(chirp)
    if not fit_alpha:
        return _identify_once(quasi_static, chirp, base, progress, correct_compressibility,
                              hysteresis_filter_on, start_factors, fixed, exclude,
                              max_valve_samples, chirp_friction_factor)
    return _identify_alpha(quasi_static, chirp, base, progress, alpha_bounds_per_pa,
                           correct_compressibility, hysteresis_filter_on, start_factors, fixed,
                           exclude, max_valve_samples, chirp_friction_factor)


def _identify_alpha(quasi_static, chirp, base, progress, bounds, *options) -> Identification:
    say = progress or (lambda msg: None)
    alpha0 = base.damper.oil_compressibility_per_pa
    lo, hi = bounds if bounds is not None else (alpha0 * ALPHA_BOUND_FACTORS[0],
                                                 alpha0 * ALPHA_BOUND_FACTORS[1])
    if not 0 < lo < hi:
        raise IdentificationError(f"α bounds must satisfy 0 < lower < upper, got ({lo:g}, {hi:g})")
    joined, _ = join_tests(chirp)
    tried: dict[float, tuple[float, Identification | None]] = {}

    def score(log_alpha: float) -> float:
        alpha = float(np.exp(log_alpha))
        try:
            ident = _identify_once(quasi_static, chirp,
                                   base.replace_damper(oil_compressibility_per_pa=alpha),
                                   None, *options)
            rms = chirp_simulation_rms(ident.config, joined)
        except IdentificationError as exc:
            say(f"α {alpha:.4g} 1/Pa: no valid identification ({exc})")
            tried[alpha] = (math.inf, None)
            return ALPHA_FAILED_SCORE
        tried[alpha] = (rms, ident)
        say(f"α {alpha:.4g} 1/Pa: compressible model r.m.s. {rms:.2f} N over the chirp "
            f"({len(tried)} tried)")
        return rms

    sol = minimize_scalar(score, bounds=(math.log(lo), math.log(hi)), method="bounded",
                          options={"xatol": ALPHA_LOG_TOLERANCE})
    best_alpha = min((a for a in tried if tried[a][1] is not None),
                     key=lambda a: tried[a][0], default=None)
    if best_alpha is None:
        raise IdentificationError(f"no α in [{lo:.3g}, {hi:.3g}] 1/Pa gives a valid "
                                  "identification")
    rms, ident = tried[best_alpha]
    at_bound = min(abs(math.log(best_alpha / lo)), abs(math.log(best_alpha / hi))) \
        < 2 * ALPHA_LOG_TOLERANCE
    say(f"α = {best_alpha:.4g} 1/Pa (chirp r.m.s. {rms:.2f} N, {len(tried)} identifications"
        f"{', AT A BOUND of the search' if at_bound else ''})")
    record = {"alpha_per_pa": best_alpha, "chirp_rms_N": rms, "bounds_per_pa": [lo, hi],
              "at_bound": bool(at_bound), "converged": bool(sol.success),
              "tried": [{"alpha_per_pa": a, "chirp_rms_N": (None if not math.isfinite(r)
                                                             else r)}
                        for a, (r, _) in sorted(tried.items())]}
    return dataclasses.replace(ident, alpha_fit=record)


def _identify_once(quasi_static, chirp, base, progress, correct_compressibility,
                   hysteresis_filter_on, start_factors, fixed, exclude=None,
                   max_valve_samples=MAX_VALVE_FIT_SAMPLES,
                   chirp_friction_factor=1.0) -> Identification:
    say = progress or (lambda msg: None)
    d = base.damper
    a_rod, a_ann, gamma = d.rod_area_m2, d.annulus_area_m2, d.gas_gamma
    nu, form = d.oil_kinematic_viscosity_m2_s, base.numerics.valve_form
    quasi_static, _ = join_tests(quasi_static)
    chirp, chirp_files = join_tests(chirp)
    fixed = fixed or {}
    if not (math.isfinite(chirp_friction_factor) and chirp_friction_factor >= 0):
        raise IdentificationError("the chirp's friction factor must be a finite number ≥ 0, "
                                  f"got {chirp_friction_factor!r}")
    unknown = set(fixed) - {"rebound", "compression"}
    if unknown:
        raise IdentificationError(f"fixed valve parameters for unknown side(s) {sorted(unknown)} "
                                  "(rebound or compression)")
    xq, vq, fq = quasi_static.displacement, quasi_static.velocity, quasi_static.force
    qs_keep = np.ones(xq.size, bool)
    chirp_drop = np.zeros(chirp.force.size, bool)
    if exclude is not None:
        for mask, n, what in zip(exclude, (xq.size, chirp.force.size),
                                 ("quasi-static", "chirp")):
            if mask is not None and np.shape(mask) != (n,):
                raise IdentificationError(f"the {what} exclusion mask has shape "
                                          f"{np.shape(mask)}, the joined record {n} samples")
        if exclude[0] is not None:
            qs_keep = ~np.asarray(exclude[0], bool)
            if qs_keep.sum() < 10:
                raise IdentificationError("fewer than 10 quasi-static samples left to fit")
        if exclude[1] is not None:
            chirp_drop = np.asarray(exclude[1], bool)
    tc, xc, vc, fc = chirp.time, chirp.displacement, chirp.velocity, chirp.force
    cfg = base
    fits: dict[str, FitResult] = {}
    previous = None
    rounds = 0
    #: each direction's first start: the centre of its valve fit's bounds in every round
    anchors: dict[str, np.ndarray] = {}
    for rounds in range(1, MAX_ROUNDS + 1):
        valve_force = (None if not fits else
                       valve_pressure_drop(vq, cfg) * a_ann)
        qs = fit_quasi_static(xq[qs_keep], vq[qs_keep], fq[qs_keep], a_rod, gamma,
                              None if valve_force is None else valve_force[qs_keep])
        p_gas, v_gas, friction = qs.values
        say(f"round {rounds}: quasi-static P_gas {p_gas / 1e6:.4f} MPa, V_gas "
            f"{v_gas * 1e6:.2f} cm³, friction {friction:.1f} N (r.m.s. {qs.rms:.2f} N)")
        parts = [valve_flow_and_pressure_drop(tc[f], xc[f], vc[f], fc[f], d, p_gas, v_gas,
                                              chirp_friction_factor * friction,
                                              correct_compressibility)
                 for f in chirp_files]
        q_all, dp_all, q_noise = (np.concatenate(a) for a in zip(*parts))
        force_sd = qs.rms  # the quasi-static residual: the force measurement's noise
        selected = [chirp_selection(tc[f], vc[f], q_all[f], dp_all[f], hysteresis_filter_on)
                    for f in chirp_files]
        masks = {side: np.concatenate([sel[k] for sel in selected]) & ~chirp_drop
                 for k, side in enumerate(("rebound", "compression"))}
        for side, m in masks.items():
            if m.sum() < 20:
                raise IdentificationError(
                    f"{chirp.name or 'chirp'}: only {int(m.sum())} {side} samples are usable "
                    "for the valve fit (need 20)")
        usable = {side: int(m.sum()) for side, m in masks.items()}
        strides = {}
        for side in masks:
            masks[side], strides[side] = thin_selection(masks[side], max_valve_samples)
        if rounds == 1 and max(strides.values()) > 1:
            say(f"round 1: the valve fits take 1 in {strides['rebound']} of the "
                f"{usable['rebound']} usable rebound and 1 in {strides['compression']} of the "
                f"{usable['compression']} compression chirp samples (at most "
                f"{max_valve_samples} per direction)")
        for side in ("rebound", "compression"):
            m = masks[side]
            qa = np.abs(q_all[m])
            if side in fits:
                start = fits[side].values
            else:
                start = start_values(qa, np.abs(dp_all[m]), nu)
                if start_factors is not None:
                    start = start * np.asarray(start_factors[side], float)
                anchors[side] = start
            weights = None
            if correct_compressibility and start is not None:
                weights = effective_variance_weights(qa, force_sd * q_noise[m], force_sd,
                                                     a_ann, start, nu, form)
            fits[side] = fit_valve(qa, np.abs(dp_all[m]), a_ann, nu, form, start, weights,
                                   fixed.get(side), anchors[side])
            say(f"round {rounds}: {side} valve r.m.s. {fits[side].rms:.2f} N "
                f"({fits[side].samples} samples)")
        current = np.concatenate((qs.values, fits["rebound"].values,
                                  fits["compression"].values))
        try:
            cfg = dataclasses.replace(base, damper=dataclasses.replace(
                d, gas_pressure_static_pa=float(p_gas), gas_volume_static_m3=float(v_gas),
                friction_force_n=float(chirp_friction_factor * friction),
                rebound=ValveParams(*map(float, fits["rebound"].values)),
                compression=ValveParams(*map(float, fits["compression"].values))))
            validate(cfg)
        except ParameterError as exc:
            raise IdentificationError(
                f"the fitted parameters are not a valid damper: {exc}") from None
        if previous is not None and np.all(np.abs(current / previous - 1) < ROUND_TOLERANCE):
            break
        previous = current
    series = {"flow_m3_s": q_all, "pressure_drop_pa": dp_all, "masks": masks,
              "quasi_static_valve_force_n": valve_force, "quasi_static": quasi_static,
              "chirp": chirp, "chirp_files": chirp_files}
    return Identification(cfg, qs, fits["rebound"], fits["compression"], rounds,
                          {k: int(m.sum()) for k, m in masks.items()}, series,
                          chirp_samples_usable=usable,
                          chirp_friction_factor=chirp_friction_factor)
