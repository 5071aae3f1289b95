"""The measurement chain estimated from the data, and the discovery of a term no library
holds, each on the truth simulation with the model that made it (so that the only thing to
find is what the test put in), against independent values: the filter's closed-form
group delay, the inertia's mass, a Gaussian profile's centre and width, and on noise only
nothing significant."""

from __future__ import annotations

import math

import numpy as np
import pytest

from damper_emulator.acquisition.chain import (
    ESTIMATED_DELAY_BOUND_S,
    ESTIMATED_DELAY_START_S,
    estimated_rig,
)
from damper_emulator.acquisition.rig import ForceChannel, RigParams
from damper_emulator.diagnose.base import ACQUISITION_DELAY, make_record
from damper_emulator.diagnose.candidates import Parameter
from damper_emulator.diagnose.discovery import FeatureSource, discover, profile_feature
from damper_emulator.diagnose.joint import Space
from damper_emulator.diagnose.outcome import MAX_DELTA_BIC, MIN_SCORE
from damper_emulator.diagnose.truth import Protocol, simulate_session
from damper_emulator.dyno.protocols import Chirp, QuasiStatic
from damper_emulator.model.compressible import DamperModel

PROTOCOL = Protocol(chirp=Chirp(duration_s=12.0), quasi_static=QuasiStatic(cycles=1))
NOISE_N = 3.0


def _records(cfg, rig=None, extra=None, seed=2):
    data = list(simulate_session(cfg, PROTOCOL, NOISE_N, seed, rig=rig,
                                 extra_force=extra).values())
    fit = [make_record(d, False) for d in data[:2]]
    held = [make_record(d, True) for d in data[2:]]
    return fit, held


def _weights(records):
    return [1.0 / (math.sqrt(r.counted) * NOISE_N) for r in records]


@pytest.fixture(scope="module")
def filtered(sport_cfg):
    rig = RigParams(force=ForceChannel(filter="butterworth", order=2, cutoff_hz=150.0,
                                       adc_bits=14, full_scale_n=10_000.0))
    return _records(sport_cfg, rig)


def test_a_fit_frees_the_delay_and_steps_it_without_simulating(sport_cfg, filtered):
    """The delay is a nuisance parameter of the fit: its Jacobian column is a filtering of
    the forces the model already gave (one simulation for the whole fit), and the fit ends
    at the filter's closed-form delay at low frequency, √2/(2π·150 Hz) = 1.50 ms."""
    fit, _ = filtered
    b = ESTIMATED_DELAY_BOUND_S
    start = {ACQUISITION_DELAY: ESTIMATED_DELAY_START_S}
    space = Space(sport_cfg, [Parameter(ACQUISITION_DELAY, 0.0, b, 0.0, False, "s")],
                  start, [], [], [], fit, _weights(fit))
    sol = space.solve(space.encode(start, []), 30)
    tau = space.decode(sol.x)[0][ACQUISITION_DELAY]
    assert tau == pytest.approx(math.sqrt(2) / (2 * math.pi * 150.0), rel=0.03)
    assert space.evaluations == 1
    sd = space.std(sol, 0.0)[(-1, ACQUISITION_DELAY)]
    assert 0.0 < sd < 0.01 * tau
    # the chain it stands for: a Butterworth filter of the same delay
    assert estimated_rig(tau).force.cutoff_hz == pytest.approx(150.0, rel=0.03)
    assert estimated_rig(-1e-3).force.skew_s == -1e-3
    assert estimated_rig(0.0).does_nothing


def test_an_inertia_is_discovered_as_mass_times_acceleration(sport_cfg):
    """A 4 kg mass between load cell and damper adds ``m ẍ`` (on the truth's grid, 4×
    the samples'), recorded through a 150 Hz load-cell filter given as the rig; on the
    model without it the discovery names the acceleration (of the recorded motion, through
    the chain), reads the mass, hints ``inertia``, and the held-out residual comes back
    to the noise."""
    import dataclasses

    mass = 4.0
    rig = RigParams(force=ForceChannel(filter="butterworth", order=2, cutoff_hz=150.0))
    fit, held = _records(sport_cfg, rig=rig,
                         extra=lambda t, x, v: mass * np.gradient(v, t))
    fit, held = ([make_record(dataclasses.replace(r.data, acquisition=rig), h) for r in rs]
                 for rs, h in ((fit, False), (held, True)))
    found = discover(DamperModel(sport_cfg), None, fit, held, _weights(fit), 0.0, 10.0,
                     1.5, MIN_SCORE, MAX_DELTA_BIC)
    assert found.ran and found.significant, found.to_json()
    terms = {f.symbol: (c, s) for f, c, s in zip(found.features, found.coefficients,
                                                  found.std)}
    c, s = terms["ẍ"]
    assert c == pytest.approx(mass, rel=0.05) and 0 < s < 0.05 * mass
    assert found.family_hint == "inertia" and "acceleration" in found.variables
    doc = found.to_json()
    assert doc["coefficients"][0]["unit"] in {"kg", "N·s/m", "N"}
    assert "kg · ẍ" in doc["expression"]
    assert max(found.rms_held_out_after.values()) < 1.5 * NOISE_N
    assert found.held_out_gain > 0.5


def test_a_gaussian_damping_zone_is_placed_and_sized(sport_cfg):
    """Damping ``c exp(−(x − x₀)²/(2w²)) ẋ`` over a zone off the dictionary's grid
    (x₀ = 8 mm, w = 6 mm): the refined profile finds its centre and width."""
    c0, x0, w = 600.0, 0.008, 0.006

    def zone(t, x, v):
        return c0 * np.exp(-0.5 * ((x - x0) / w) ** 2) * v

    fit, held = _records(sport_cfg, extra=zone)
    found = discover(DamperModel(sport_cfg), None, fit, held, _weights(fit), 0.0, 10.0,
                     1.5, MIN_SCORE, MAX_DELTA_BIC)
    assert found.significant, found.to_json()
    prof = [f for f in found.features if f.profile is not None]
    assert prof, found.expression
    centre, width = prof[0].profile
    assert centre == pytest.approx(x0, abs=1e-3) and width == pytest.approx(w, rel=0.15)
    assert found.family_hint == "position_dependent"
    c = found.coefficients[found.features.index(prof[0])]
    assert c == pytest.approx(c0, rel=0.05)
    # once the profile is placed, nothing else is needed
    assert len(found.features) == 1, found.expression


def test_a_zones_place_is_fitted_in_the_joint_fit_without_simulating(sport_cfg):
    """A zone's centre and width are parameters of the joint fit beside its gain
    (``FeatureSource``): made of the measured motion alone, a step of them recomputes a
    column and simulates nothing.  On the model that made the data, from a zone 2 mm off
    and a third too narrow at two thirds of the gain, the fit lands on the truth's
    (x₀ = 8 mm, w = 6 mm, 600 N·s/m) with one simulation of the records in all."""
    c0, x0, w = 600.0, 0.008, 0.006
    fit, _ = _records(sport_cfg,
                      extra=lambda t, x, v: c0 * np.exp(-0.5 * ((x - x0) / w) ** 2) * v)
    source = FeatureSource([profile_feature(x0 + 0.002, w * 2 / 3)], fit)
    params, start = source.parameters([c0 * 2 / 3])
    space = Space(sport_cfg, params, start, [], [], [], fit, _weights(fit), terms=source)
    sol = space.solve(space.encode(start, []), 40)
    values = space.decode(sol.x)[0]
    (zone,) = source.fitted(values)
    centre, width = zone.profile
    assert centre == pytest.approx(x0, abs=1e-4)
    assert width == pytest.approx(w, rel=0.02)
    assert values[params[0].name] == pytest.approx(c0, rel=0.02)
    assert space.evaluations == 1


def test_a_seal_friction_that_grows_with_the_gas_pressure_reads_as_friction(sport_cfg):
    """A seal pressed by the gas: ``μ_A p_gas(x) tanh(ẋ / 2 mm/s)``, the gas pressure of
    eq 3 (adiabatic, of the stroke alone) and a sharper sign than the dictionary's
    5 mm/s.  The term found is the compression chamber's pressure times the sign, its
    width refined to the seal's 2 mm/s and its coefficient the seal's μ_A (the chamber's
    pressure is the gas's, to the valve's drop in compression); it hints ``friction``
    and leaves the held-out residual near the noise."""
    d = sport_cfg.damper
    mu_area = 1.2e-5  # m²: 36 N of friction at the 3 MPa charge

    def seal(t, x, v):
        # eq 3 by hand: extension enlarges the gas volume by A_rod x
        p_gas = d.gas_pressure_static_pa * (d.gas_volume_static_m3 / (
            d.gas_volume_static_m3 + d.rod_area_m2 * x)) ** d.gas_gamma
        return mu_area * p_gas * np.tanh(v / 0.002)

    fit, held = _records(sport_cfg, extra=seal)
    found = discover(DamperModel(sport_cfg), None, fit, held, _weights(fit), 0.0, 10.0,
                     1.5, MIN_SCORE, MAX_DELTA_BIC)
    assert found.significant and found.family_hint == "friction", found.to_json()
    assert "friction" in found.variables
    (seal_part,) = [f for f in found.features if f.symbol.startswith("p_c ·")]
    assert seal_part.sign_m_s == pytest.approx(0.002, rel=0.1)
    c = found.coefficients[found.features.index(seal_part)]
    assert c == pytest.approx(mu_area, rel=0.05)
    assert max(found.rms_held_out_after.values()) < 1.5 * NOISE_N


def test_noise_alone_gives_no_significant_term(sport_cfg):
    """The model that made the data leaves white noise: whatever the stability selection
    keeps, it is not significant by the candidates' rules."""
    fit, held = _records(sport_cfg, seed=7)
    found = discover(DamperModel(sport_cfg), None, fit, held, _weights(fit), 0.0, 10.0,
                     1.5, MIN_SCORE, MAX_DELTA_BIC)
    assert found.ran and not found.significant, found.to_json()
    assert found.held_out_gain < MIN_SCORE
    # and the gate: the residual's structure ratio is that of white noise
    gated = discover(DamperModel(sport_cfg), None, fit, held, _weights(fit), 0.0, 1.0,
                     1.5, MIN_SCORE, MAX_DELTA_BIC)
    assert not gated.ran and "nothing to discover" in gated.reason


@pytest.mark.parametrize(("per_file", "pooled", "stable", "why"), [
    ({"a": (6.0, 0.1), "b": (5.8, 0.2), "c": (6.3, 0.3)}, 6.0, True, ""),
    # 5.0 … 8.5: more than half the value
    ({"a": (5.0, 0.1), "b": (8.5, 0.2)}, 6.0, False, "spans 58 %"),
    ({"a": (6.0, 0.1), "b": (-2.0, 0.2)}, 6.0, False, "sign changes"),
    # one file determines it (the other's σ is more than half its value)
    ({"a": (6.0, 0.1), "b": (6.0, 4.0)}, 6.0, False, "1 file(s) only"),
])
def test_a_term_is_stable_when_every_file_that_determines_it_agrees(per_file, pooled,
                                                                    stable, why):
    from damper_emulator.diagnose.term_trust import stable_over

    ok, reason = stable_over(per_file, pooled)
    assert ok is stable and why in reason


def test_a_known_form_of_the_wrong_sign_is_not_that_physics(sport_cfg):
    """A force ``−4 kg · ẍ`` (a negative mass: no inertia does that) is not discovered as a
    mass, though the acceleration would fit it; an effect outside the library that is a
    positive mass is (the test above)."""
    fit, held = _records(sport_cfg, extra=lambda t, x, v: -4.0 * np.gradient(v, t))
    found = discover(DamperModel(sport_cfg), None, fit, held, _weights(fit), 0.0, 10.0,
                     1.5, MIN_SCORE, MAX_DELTA_BIC)
    assert all(f.symbol != "ẍ" for f in found.features), found.expression


def test_a_zone_behind_a_bent_valve_is_found_with_the_models_parameters_free(sport_cfg):
    """The zone of the test above, on a model whose rebound valve's port is 2.5 times too
    stiff (a fit that bent it towards what it lacked): the residual is the zone and that
    bend.  With the model's parameters free to first order beside the term (their slopes
    at the bent model, ``ModelFree``), the term is the zone alone, with the truth's centre,
    width and damping, closer than without them, where the bend leaves its mark on the
    zone's profile."""
    from damper_emulator.diagnose.base import base_parameters, config_with
    from damper_emulator.diagnose.discovery import ModelFree
    from damper_emulator.diagnose.joint import model_jacobians

    c0, x0, w = 600.0, 0.008, 0.006

    def zone(t, x, v):
        return c0 * np.exp(-0.5 * ((x - x0) / w) ** 2) * v

    fit, held = _records(sport_cfg, extra=zone)
    bent = config_with(sport_cfg, {"rebound.k_port": 2.5 * sport_cfg.damper.rebound.k_port})
    values = {p.name: p.start for p in base_parameters(bent, [r.data for r in fit])}
    weights = _weights(fit)
    on_fit, on_held = model_jacobians(bent, values, [], fit, held, weights, 1)
    assert on_fit.shape == (sum(r.counted for r in fit), len(values))
    assert on_held.shape == (sum(r.counted for r in held), len(values))
    found, plain = (discover(DamperModel(bent), None, fit, held, weights, 0.0, 10.0, 1.5,
                             MIN_SCORE, MAX_DELTA_BIC, free=free)
                    for free in (ModelFree(on_fit, on_held), None))
    assert found.significant and len(found.features) == 1, found.expression
    (feature,) = found.features
    assert feature.profile is not None, found.expression
    centre, width = feature.profile
    assert centre == pytest.approx(x0, abs=2e-4) and width == pytest.approx(w, rel=0.03)
    assert found.coefficients[0] == pytest.approx(c0, rel=0.02)
    assert plain.significant and len(plain.features) == 1, plain.expression
    assert abs(found.coefficients[0] - c0) < abs(plain.coefficients[0] - c0)
