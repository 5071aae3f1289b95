"""Residual analysis (damper_emulator.diagnose.residual): known disturbances added to the
model's own simulated sine must be found by the feature that is meant to find them."""

import math

import numpy as np
import pytest

from damper_emulator.diagnose import plot_residual, residual_features, residual_record
from damper_emulator.diagnose.residual import binned_r2
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.model.compressible import simulate

FREQ = 2.0       # Hz
AMP = 0.02       # m
CYCLES = 4
RATE = 1000.0    # Hz


@pytest.fixture(scope="module")
def sine(sport_model):
    """The model's own force on a 2 Hz sine (4 whole cycles, 1 kHz)."""
    t = np.arange(int(CYCLES * RATE / FREQ)) / RATE
    w = 2.0 * math.pi * FREQ
    x = AMP * np.sin(w * t)
    v = AMP * w * np.cos(w * t)
    f = simulate(sport_model, t, x, v).force_n
    return t, x, v, f


def features_with(model, sine, extra, **kw):
    t, x, v, f = sine
    data = MeasuredData(time=t, displacement=x, force=f + extra, velocity=v,
                        name="sine.csv", **kw)
    rec = residual_record(model, data)
    return rec, residual_features(rec)


R2_KEYS = ("r2_velocity", "r2_displacement", "r2_acceleration", "r2_time_linear",
           "r2_energy_linear")


def test_model_on_its_own_data_has_no_residual(sport_model, sine):
    rec, feats = features_with(sport_model, sine, 0.0)
    assert feats["rms_N"] < 1e-6
    np.testing.assert_allclose(rec.force_model, sine[3], atol=1e-6)
    assert math.isnan(feats["r2_temperature"])  # no temperature channel
    for key, val in feats.items():
        if key != "r2_temperature":
            assert math.isfinite(val), key
    for key in R2_KEYS:
        assert 0.0 <= feats[key] <= 1.0
    # the energy is the loop work: positive for a damper, one loop ≈ energy / cycles
    assert feats["energy_total_J"] > 0
    # acceleration of a sine: −ω² x (a quadratic Savitzky–Golay over 25 ms at 2 Hz is
    # within 0.3 % of it)
    w = 2.0 * math.pi * FREQ
    np.testing.assert_allclose(rec.acceleration, -w * w * rec.displacement,
                               atol=5e-3 * w * w * AMP)
    # deterministic
    assert residual_features(rec) == feats


def test_coulomb_term_is_a_function_of_velocity(sport_model, sine):
    v = sine[2]
    extra = 30.0 * np.tanh(v / 0.005)
    _rec, feats = features_with(sport_model, sine, extra)
    assert feats["r2_velocity"] > 0.95
    assert feats["corr_sign_velocity"] > 0.95
    assert feats["r2_displacement"] < 0.05
    # near-reversal ratio, computed here from the tanh itself
    thr = 0.05 * np.percentile(np.abs(v), 99.0)
    near = np.abs(v) <= thr
    expected = (np.sqrt(np.mean(extra[near] ** 2)) / np.sqrt(np.mean(extra[~near] ** 2)))
    assert feats["reversal_rms_ratio"] == pytest.approx(expected, rel=1e-3)
    assert feats["reversal_rms_ratio"] < 0.8  # friction is small near v = 0 for a tanh
    # the quadrants see +30 N in extension and −30 N in compression
    assert feats["quadrant_ext_dec_mean_N"] > 25 and feats["quadrant_comp_acc_mean_N"] < -25


def test_linear_drift_is_a_function_of_time(sport_model, sine):
    t = sine[0]
    extra = 50.0 * t / t[-1]
    _, feats = features_with(sport_model, sine, extra)
    assert feats["r2_time_linear"] > 0.99
    assert feats["drift_N_per_s"] == pytest.approx(50.0 / t[-1], rel=1e-6)
    assert feats["r2_velocity"] < 0.1
    assert feats["r2_energy_linear"] > 0.9  # the energy grows with time too


def test_spring_term_is_a_function_of_displacement(sport_model, sine):
    x = sine[1]
    _, feats = features_with(sport_model, sine, 2000.0 * x)
    assert feats["r2_displacement"] > 0.99
    assert feats["r2_velocity"] < 0.05
    assert abs(feats["corr_sign_velocity"]) < 0.05


def test_third_harmonic_is_found_in_the_spectrum(sport_model, sine):
    t = sine[0]
    extra = 20.0 * np.sin(2.0 * math.pi * 3.0 * FREQ * t + 0.3)
    _, feats = features_with(sport_model, sine, extra)
    assert feats["spectrum_fundamental_hz"] == pytest.approx(FREQ)
    assert feats["spectrum_dominant_harmonic"] == 3
    assert feats["spectrum_fraction_h3"] > 0.9
    assert feats["spectrum_fraction_broadband"] < 0.1


def test_white_noise_is_white_and_unexplained(sport_model, sine):
    noise = np.random.default_rng(7).normal(0.0, 5.0, sine[0].size)
    _, feats = features_with(sport_model, sine, noise)
    assert feats["rms_N"] == pytest.approx(5.0, rel=0.05)
    assert abs(feats["lag1_autocorrelation"]) < 0.08
    for key in R2_KEYS:
        assert feats[key] < 0.05, key
    assert feats["spectrum_fraction_broadband"] > 0.8


def test_binned_r2_of_a_constant_channel_is_zero():
    r = np.random.default_rng(1).normal(size=500)
    assert binned_r2(r, np.full(500, 25.0)) == 0.0
    assert binned_r2(np.zeros(500), np.arange(500.0)) == 0.0


def test_temperature_channel_and_estimated_velocity_and_plot(sport_model, sine, tmp_path):
    t, x, _v, f = sine
    temp = 25.0 + 10.0 * t / t[-1]
    extra = 3.0 * (temp - 25.0)  # fade with temperature
    data = MeasuredData(time=t, displacement=x, force=f + extra, temperature=temp,
                        name="warm.csv")  # no velocity column: Savitzky–Golay derivative
    rec = residual_record(sport_model, data)
    assert rec.info["velocity_source"] == "savgol"
    feats = residual_features(rec)
    assert all(math.isfinite(val) for val in feats.values())
    assert feats["r2_temperature"] > 0.95
    png = plot_residual(tmp_path / "residual.png", rec, "test")
    assert png.stat().st_size > 10_000


def test_a_rest_at_the_end_is_trimmed_not_read_as_friction(sport_model, sine):
    """The rig standing still after the test, with a load-cell offset there: the features
    are those of the moving record (the rest is trimmed), not a reversal signature."""
    from damper_emulator.diagnose.residual import trim_rest

    t, x, v, f = sine
    extra = 30.0 * np.tanh(v / 0.005)            # a real friction-like residual
    _, moving = features_with(sport_model, sine, extra)
    n_rest = int(0.6 * RATE)
    t2 = np.concatenate([t, t[-1] + (1 + np.arange(n_rest)) / RATE])
    x2 = np.concatenate([x, np.full(n_rest, x[-1])])
    v2 = np.concatenate([v, np.zeros(n_rest)])
    f_rest = simulate(sport_model, t2, x2, v2).force_n
    offset = np.concatenate([extra, np.full(n_rest, 13.0)])
    data = MeasuredData(time=t2, displacement=x2, force=f_rest + offset, velocity=v2,
                        name="sine_rest.csv")
    rec = residual_record(sport_model, data)
    trimmed, rest_s = trim_rest(rec)
    assert len(trimmed) < len(rec)
    assert rest_s == pytest.approx(0.6, abs=0.02)
    feats = residual_features(rec)
    assert feats["rest_trimmed_s"] == pytest.approx(rest_s)
    for key in ("reversal_rms_ratio", "corr_sign_velocity", "r2_velocity"):
        assert feats[key] == pytest.approx(moving[key], abs=0.02), key
    # nothing to trim in a record that moves from start to end
    assert trim_rest(residual_record(sport_model, MeasuredData(
        time=t, displacement=x, force=f, velocity=v, name="s")))[1] == 0.0


def test_residual_through_an_estimated_chain(sport_model, sine):
    """A record whose force is late by τ (what the estimated chain, a load-cell filter
    of group delay τ, stands for) leaves no residual against the model recorded through
    that chain: the filter's phase is τ·ω to O((f/f_c)³) within the force's harmonics
    (not across eq 4's friction switch at the reversals, where the pure delay and the
    filter differ by a few per cent of the delay's residual)."""
    from damper_emulator.acquisition.chain import estimated_rig

    t, x, v, f = sine
    tau = 2e-3
    late = np.interp(t - tau, t, f)
    data = MeasuredData(time=t, displacement=x, force=late, velocity=v, name="late.csv")
    k = int(RATE / FREQ)  # from the second cycle on (the filter's start-up)
    plain = residual_record(sport_model, data).residual[k:]
    chained = residual_record(sport_model, data, estimated_rig(tau)).residual[k:]
    rms = lambda a: float(np.sqrt(np.mean(a * a)))  # noqa: E731
    assert rms(plain) > 10.0
    assert rms(chained) < 0.1 * rms(plain)
