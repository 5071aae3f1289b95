"""The discovered term as a model extension (``damper.extensions.discovered_term``): what
the compiled step adds, against closed forms (a mass times the derivative of a sine, a
first-order lag's steady sine response, a Gaussian zone, the energy integral), the
real-time stepper against the batch simulation, and the discovery's dictionary against
the step (one implementation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from damper_emulator.diagnose.base import make_record
from damper_emulator.diagnose.discovery import _features, motion, term_params
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.dyno.protocols import chirp, sine
from damper_emulator.model.compressible import DamperStepper, simulate
from damper_emulator.model.discovered import N_TERMS, lag_history
from damper_emulator.params import (
    DiscoveredTermParams,
    ExtensionParams,
    config_from_mapping,
    config_to_mapping,
)
from damper_emulator.schema import ParameterError


def _with(model, **coefficients):
    return model.with_extensions(ExtensionParams(
        discovered_term=DiscoveredTermParams(**coefficients)))


def _added(model, t, x, v, **coefficients):
    """The force the term adds on the history ``(t, x, v)``."""
    return (simulate(_with(model, **coefficients), t, x, v).force_n
            - simulate(model, t, x, v).force_n)


def test_a_mass_adds_mass_times_the_derivative_of_the_velocity(sport_model):
    """``m ẍ`` of ``x = X sin ωt``: ``−m X ω² sin ωt``; the three-point backward formula's
    error is ``(ω h)² / 3`` of it (3.3e-4 at 5 Hz and 1 kHz)."""
    t, x, v = sine(5.0, 0.02, 3, rate_hz=1000.0)
    added = _added(sport_model, t, x, v, acceleration_kg=6.0)
    w = 2.0 * math.pi * 5.0
    exact = -6.0 * 0.02 * w * w * np.sin(w * t)
    amp = 6.0 * 0.02 * w * w
    assert np.max(np.abs(added[2:] - exact[2:])) < 1e-3 * amp
    assert added[0] == 0.0  # the settled start is at rest


def test_an_inertia_adds_mass_times_the_derivative_of_the_velocity(sport_model):
    """The ``inertia`` extension: ``m ẍ`` of ``x = X sin ωt`` within the backward formula's
    ``(ω h)² / 3``, and beside a discovered term's own acceleration the masses add."""
    from damper_emulator.params import InertiaParams

    t, x, v = sine(5.0, 0.02, 3, rate_hz=1000.0)
    heavy = sport_model.with_extensions(ExtensionParams(inertia=InertiaParams(6.0)))
    added = simulate(heavy, t, x, v).force_n - simulate(sport_model, t, x, v).force_n
    w = 2.0 * math.pi * 5.0
    exact = -6.0 * 0.02 * w * w * np.sin(w * t)
    assert np.max(np.abs(added[2:] - exact[2:])) < 1e-3 * 6.0 * 0.02 * w * w
    both = sport_model.with_extensions(ExtensionParams(
        inertia=InertiaParams(2.0), discovered_term=DiscoveredTermParams(acceleration_kg=4.0)))
    np.testing.assert_allclose(simulate(both, t, x, v).force_n,
                               simulate(heavy, t, x, v).force_n, rtol=1e-12, atol=1e-9)


def test_the_lag_follows_a_sine_as_a_first_order_lag():
    """Steady state of ``τ ẏ = F − y`` for ``F = sin ωt``: gain ``1/√(1 + (ωτ)²)``, phase
    ``−atan ωτ``; the kernel is exact for a force linear between samples."""
    tau, f_hz = 0.01, 8.0
    t = np.arange(0.0, 2.0, 1e-3)
    w = 2.0 * math.pi * f_hz
    force = np.sin(w * t)
    out = np.empty_like(t)
    lag_history(t, force, tau, out)
    y = np.sin(w * t - math.atan(w * tau)) / math.sqrt(1.0 + (w * tau) ** 2)
    late = t > 10 * tau * 5
    assert np.max(np.abs(out[late] - (y[late] - force[late]))) < 2e-4


def test_a_zone_of_damping_is_a_gaussian_times_the_velocity(sport_model):
    t, x, v = sine(2.0, 0.03, 2, rate_hz=1000.0)
    added = _added(sport_model, t, x, v, profile_n_s_m=900.0, profile_center_m=0.01,
                   profile_width_m=0.004)
    exact = 900.0 * np.exp(-0.5 * ((x - 0.01) / 0.004) ** 2) * v
    np.testing.assert_allclose(added, exact, atol=1e-9 * np.max(np.abs(exact)))


def test_the_energy_is_the_work_of_the_models_force(sport_model):
    """``E F`` with ``E = ∫ F ẋ dt`` of the model's own force: against the trapezoid
    integral of that force (the rule differs, the integral converges)."""
    t, x, v = sine(3.0, 0.02, 3, rate_hz=2000.0)
    f = simulate(sport_model, t, x, v).force_n
    k = 1e-6
    added = _added(sport_model, t, x, v, energy_force_per_j=k)
    energy = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] * v[1:] + f[:-1] * v[:-1])
                                              * np.diff(t))])
    assert energy[-1] > 100.0  # the damper dissipates
    np.testing.assert_allclose(added[1:] / (k * f[1:]), energy[1:],
                               atol=5e-3 * energy[-1])


def test_the_stepper_runs_the_term_as_the_batch_does(sport_model):
    """One implementation: the real-time stepper, sample by sample, gives the batch
    simulation's forces, a measured temperature included."""
    model = _with(sport_model, acceleration_kg=4.0, smooth_sign_n=30.0,
                  temperature_force_per_k=0.002, reference_temperature_c=40.0,
                  lag_coefficient=0.3, lag_time_constant_s=0.004)
    t, x, v = chirp(0.5, 10.0, duration_s=1.0, v_start_m_s=0.05, v_end_m_s=0.6,
                    rate_hz=1000.0)
    temp = np.linspace(30.0, 60.0, t.size)
    batch = simulate(model, t, x, v, temperature_c=temp).force_n
    s = DamperStepper(model)
    s.set_temperature(float(temp[0]))
    s.reset(float(x[0]), float(v[0]))
    stepped = [s.force_n]
    for i in range(1, t.size):
        s.set_temperature(float(temp[i]))
        stepped.append(s.step(float(x[i]), float(v[i]), float(t[i] - t[i - 1]))[0])
    np.testing.assert_allclose(stepped, batch, rtol=1e-9, atol=1e-6)
    assert np.ptp(batch - simulate(sport_model, t, x, v, temperature_c=temp).force_n) > 50.0


def test_the_dictionary_is_the_steps_features(sport_model):
    """The discovery's columns are the features the step evaluates: the model with the
    term ``Σ cₖ fₖ`` adds exactly the dictionary's ``Σ cₖ columnₖ``."""
    t, x, v = chirp(0.5, 10.0, duration_s=1.0, v_start_m_s=0.05, v_end_m_s=0.6,
                    rate_hz=1000.0)
    data = MeasuredData(time=t, displacement=x, force=np.zeros_like(t), velocity=v,
                        temperature=None, name="probe")
    rec = make_record(data, False)
    m = motion(sport_model, rec, 0.03, 0.0)
    assert m.terms.shape == (t.size, N_TERMS)
    feats = _features(0.03)
    by_symbol = {f.symbol: f for f in feats}
    chosen = [by_symbol["ẍ"], by_symbol["x²"], next(f for f in feats if f.profile),
              next(f for f in feats if f.lag_s)]
    coef = [3.0, 2e4, 500.0, 0.2]
    expected = sum(c * f.fn(m) for c, f in zip(coef, chosen))
    params = term_params(chosen, coef, 0.0)
    model = sport_model.with_extensions(ExtensionParams(discovered_term=params))
    added = simulate(model, t, x, v).force_n - m.force_model
    np.testing.assert_allclose(added, expected, atol=1e-6 * np.max(np.abs(expected)))


def test_a_term_round_trips_through_a_params_file(sport_cfg):
    doc = config_to_mapping(sport_cfg)
    doc["/**"]["ros__parameters"]["damper"]["extensions"] = {
        "discovered_term": {"acceleration_kg": 5.9, "profile_n_s_m": -40.0,
                            "profile_width_m": 0.01}}
    cfg = config_from_mapping(doc)
    assert cfg.damper.extensions.discovered_term.acceleration_kg == 5.9
    assert config_from_mapping(config_to_mapping(cfg)) == cfg
    doc["/**"]["ros__parameters"]["damper"]["extensions"]["discovered_term"][
        "acceleration_kg"] = float("nan")
    with pytest.raises(ParameterError, match=r"acceleration_kg .* must be finite"):
        config_from_mapping(doc)


def test_without_the_term_the_step_is_the_papers_model(sport_model):
    t, x, v = chirp(0.5, 10.0, duration_s=1.0, rate_hz=1000.0)
    zero = _with(sport_model)  # every coefficient 0
    np.testing.assert_array_equal(simulate(zero, t, x, v).force_n,
                                  simulate(sport_model, t, x, v).force_n)
