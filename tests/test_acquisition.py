"""The rig's measurement chain (``damper_emulator.acquisition``) against independent
derivations: the analog filters' closed-form frequency and step responses, their group
delay at zero frequency, the converter's rounding, the skew; the rig file's schema and its
one-line errors; and ``validate --rig`` on a recording made through a rig, where the model
that made it must come back to the noise only through the chain.
"""

import math

import numpy as np
import pytest

from damper_emulator.acquisition.chain import (
    dc_group_delay,
    delayed,
    filter_samples,
    model_record,
    quantise,
    record_channel,
    relative_delay,
)
from damper_emulator.acquisition.rig import (
    DisplacementChannel,
    ForceChannel,
    RigParams,
    load_rig,
    rig_from_mapping,
    rig_to_mapping,
)
from damper_emulator.dyno.measured import read_measured_csv, write_measured_csv
from damper_emulator.params import DEFAULT_PARAMS_FILE
from damper_emulator.schema import ParameterError


def _steady_phasor(t: np.ndarray, y: np.ndarray, f: float, cycles: int) -> complex:
    """The complex amplitude of ``y`` at ``f`` over the last ``cycles`` whole periods."""
    n = int(round(cycles / f / (t[1] - t[0])))
    tt, yy = t[-n:], y[-n:]
    return complex(2.0 / n * np.sum(yy * np.exp(-2j * math.pi * f * tt)))


def butterworth2(f: float, fc: float) -> complex:
    """``H(jω)`` of the 2nd-order Butterworth low-pass, ``1 / (1 − w² + j√2 w)``,
    ``w = f/f_c`` (by hand, not scipy's design)."""
    w = f / fc
    return 1.0 / complex(1.0 - w * w, math.sqrt(2.0) * w)


@pytest.mark.parametrize("f", [3.0, 12.0, 60.0, 150.0])
def test_second_order_butterworth_matches_its_closed_form(f):
    ch = ForceChannel(filter="butterworth", order=2, cutoff_hz=200.0)
    rate = 200 * f  # a whole number of samples per period
    t = np.arange(0.0, 12.0 / f + 0.2, 1.0 / rate)
    c = _steady_phasor(t, filter_samples(t, np.sin(2 * math.pi * f * t), ch), f, 4)
    h = butterworth2(f, 200.0)
    # sin = Im e^{jωt}: the phasor of the output over that of the input (−j)
    got = c / -1j
    assert abs(got) == pytest.approx(abs(h), rel=2e-4)
    assert np.angle(got) == pytest.approx(np.angle(h), abs=2e-4)


@pytest.mark.parametrize("order", [1, 3, 4, 6])
def test_butterworth_gain_is_the_maximally_flat_closed_form(order):
    """``|H(jω)|² = 1 / (1 + (f/f_c)^(2n))`` for every order; at f_c: −3 dB."""
    fc, rate = 100.0, 9_000.0
    ch = ForceChannel(filter="butterworth", order=order, cutoff_hz=fc)
    for f in (30.0, 100.0, 180.0):  # whole numbers of samples per period
        t = np.arange(0.0, 30.0 / f + 0.5, 1.0 / rate)
        c = _steady_phasor(t, filter_samples(t, np.cos(2 * math.pi * f * t), ch), f, 10)
        # the samples are filtered as the signal linear between them, whose spectrum is
        # the sine's times the triangle's, sinc²(f/f_s)
        hold = np.sinc(f / rate) ** 2
        assert abs(c) == pytest.approx(hold / math.sqrt(1.0 + (f / fc) ** (2 * order)),
                                       rel=1e-5)


def test_bessel_is_minus_3_db_at_its_cutoff_and_nearly_a_pure_delay_below():
    fc, rate = 100.0, 10_000.0  # whole numbers of samples per period
    ch = ForceChannel(filter="bessel", order=4, cutoff_hz=fc)
    tau = dc_group_delay(ch)
    t = np.arange(0.0, 1.5, 1.0 / rate)
    c_cut = _steady_phasor(t, filter_samples(t, np.cos(2 * math.pi * fc * t), ch), fc, 50)
    assert abs(c_cut) == pytest.approx(1.0 / math.sqrt(2.0), rel=1e-3)
    # well below the cut-off a Bessel filter's phase is −ωτ (its maximally flat delay)
    f = 10.0
    c = _steady_phasor(t, filter_samples(t, np.cos(2 * math.pi * f * t), ch), f, 5)
    assert -np.angle(c) / (2 * math.pi * f) == pytest.approx(tau, rel=2e-3)


def test_dc_group_delay_closed_forms():
    # 1st order: 1/ω_c; 2nd-order Butterworth: √2/ω_c (ζ = 1/√2: 2ζ/ω_c)
    for fc in (50.0, 200.0, 1000.0):
        wc = 2 * math.pi * fc
        assert dc_group_delay(ForceChannel(filter="butterworth", order=1, cutoff_hz=fc)) \
            == pytest.approx(1.0 / wc, rel=1e-12)
        assert dc_group_delay(ForceChannel(filter="butterworth", order=2, cutoff_hz=fc)) \
            == pytest.approx(math.sqrt(2.0) / wc, rel=1e-12)
    assert dc_group_delay(ForceChannel()) == 0.0


def test_step_response_of_the_recording_matches_the_second_order_closed_form():
    """A unit step on the fine grid, recorded at 1 kHz: ``1 − e^(−ζω t)(cos ω_d t +
    ζ/√(1−ζ²) sin ω_d t)``, ζ = 1/√2, ω = 2π f_c."""
    fc = 200.0
    ch = ForceChannel(filter="butterworth", order=2, cutoff_hz=fc)
    fine = np.arange(-0.01, 0.05, 1.0 / 64_000.0)
    y = (fine >= 0.0).astype(float)
    t_s = np.arange(0.0, 0.04, 1e-3)
    got = record_channel(fine, y, ch, t_s)
    w, z = 2 * math.pi * fc, 1.0 / math.sqrt(2.0)
    wd = w * math.sqrt(1 - z * z)
    # the fine grid's step rises over its last interval, on average half a step earlier
    ts = t_s + 0.5 / 64_000.0
    want = 1 - np.exp(-z * w * ts) * (np.cos(wd * ts) + z / math.sqrt(1 - z * z)
                                     * np.sin(wd * ts))
    np.testing.assert_allclose(got, want, atol=2e-4)


def test_the_converter_rounds_to_its_step_and_clips_at_its_range():
    ch = ForceChannel(adc_bits=12, full_scale_n=10_000.0)
    step = 20_000.0 / 4096
    assert ch.adc_step == step
    y = np.random.default_rng(3).uniform(-9000.0, 9000.0, 20_000)
    q = quantise(y, ch)
    assert np.all(np.abs(q - y) <= step / 2 + 1e-9)
    assert np.allclose(q / step, np.round(q / step))
    # rounding error is uniform: its variance step²/12
    assert np.var(q - y) == pytest.approx(step ** 2 / 12, rel=0.05)
    assert quantise(np.array([2e4, -2e4]), ch).tolist() == [10_000.0 - step, -10_000.0]
    assert quantise(y, ForceChannel()) is y


def test_skew_delays_the_channel():
    ch = ForceChannel(skew_s=2.5e-3)
    fine = np.arange(0.0, 1.0, 1e-4)
    t_s = np.arange(0.1, 0.9, 1e-3)
    got = record_channel(fine, np.sin(2 * math.pi * 5 * fine), ch, t_s)
    np.testing.assert_allclose(got, np.sin(2 * math.pi * 5 * (t_s - 2.5e-3)), atol=2e-5)
    assert np.array_equal(delayed(t_s, got, 0.0), got)


def test_a_jittered_time_column_filters_as_the_uniform_one():
    ch = ForceChannel(filter="butterworth", order=2, cutoff_hz=100.0)
    t = np.arange(0.0, 2.0, 1e-3)
    jit = t + np.random.default_rng(1).uniform(-2e-5, 2e-5, t.size)
    jit[0] = 0.0
    sig = lambda s: np.sin(2 * math.pi * 4 * s)  # noqa: E731
    a = filter_samples(t, sig(t), ch)
    b = filter_samples(jit, sig(jit), ch)
    # the same filter: b at the jittered times is a read at those times
    np.testing.assert_allclose(b, np.interp(jit, t, a), atol=2e-3)


def test_model_record_delays_by_the_force_channel_against_the_displacement_channel():
    rig = RigParams(force=ForceChannel(skew_s=1e-3),
                    displacement=DisplacementChannel(filter="butterworth", order=1,
                                                     cutoff_hz=500.0, skew_s=0.5e-3))
    tau = 1e-3 - 0.5e-3 - 1.0 / (2 * math.pi * 500.0)
    t = np.arange(0.0, 1.0, 1e-4)
    got = model_record(t, np.sin(2 * math.pi * 3 * t), rig)
    np.testing.assert_allclose(got, np.sin(2 * math.pi * 3 * (t - tau)), atol=1e-6)
    assert relative_delay(rig) == pytest.approx(tau)


def test_a_force_channels_gain_and_zero_are_applied_after_its_filter():
    """``gain · F + zero + drift · (t − t₀)`` on the (filtered, delayed) force, ``t₀`` the
    file's first sample; identify's staged fits take them out again."""
    import dataclasses

    from damper_emulator.acquisition.chain import unscaled
    from damper_emulator.dyno.measured import MeasuredData
    from damper_emulator.identify.pipeline import aligned

    ch = ForceChannel(gain=1.05, zero_offset_n=12.0, zero_drift_n_per_s=0.5)
    t = np.arange(2.0, 5.0, 1e-3)
    f = 800.0 * np.sin(2 * math.pi * 3 * t)
    np.testing.assert_allclose(model_record(t, f, RigParams(force=ch)),
                               1.05 * f + 12.0 + 0.5 * (t - 2.0))
    filtered = RigParams(force=dataclasses.replace(ch, filter="butterworth", order=2,
                                                   cutoff_hz=200.0))
    plain = RigParams(force=ForceChannel(filter="butterworth", order=2, cutoff_hz=200.0))
    np.testing.assert_allclose(model_record(t, f, filtered),
                               1.05 * model_record(t, f, plain) + 12.0 + 0.5 * (t - 2.0))
    np.testing.assert_allclose(unscaled(t, 1.05 * f + 12.0 + 0.5 * (t - 2.0), ch), f,
                               atol=1e-9)
    assert not RigParams(force=ForceChannel(gain=1.02)).does_nothing
    data = MeasuredData(t, np.zeros_like(t), 1.05 * f + 12.0 + 0.5 * (t - 2.0),
                        acquisition=RigParams(force=ch))
    np.testing.assert_allclose(aligned(data).force, f, atol=1e-9)


# --------------------------------------------------------------------------------------
# The rig file


def test_rig_file_round_trip_and_defaults(tmp_path):
    import yaml

    rig = RigParams(force=ForceChannel(filter="bessel", order=4, cutoff_hz=300.0,
                                       adc_bits=16, full_scale_n=5000.0, skew_s=1e-4,
                                       gain=0.98, zero_offset_n=-3.5,
                                       zero_drift_n_per_s=0.01))
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump(rig_to_mapping(rig)))
    assert load_rig(p) == rig
    assert rig_from_mapping({"rig": None}) == RigParams()
    assert RigParams().does_nothing and not rig.does_nothing
    # under a node's ros__parameters too
    assert rig_from_mapping({"dyno": {"ros__parameters": rig_to_mapping(rig)}}) == rig


@pytest.mark.parametrize(("doc", "words"), [
    ({"rig": {"forse": {}}}, "unknown channel rig.forse"),
    ({"rig": {"force": {"cutoff": 200}}}, "unknown parameter rig.force.cutoff"),
    ({"rig": {"force": {"filter": "chebyshev"}}}, "rig.force.filter"),
    ({"rig": {"force": {"order": 9}}}, "rig.force.order = 9 must lie in [1, 8]"),
    ({"rig": {"force": {"cutoff_hz": -1}}}, "rig.force.cutoff_hz = -1 must be positive"),
    ({"rig": {"displacement": {"adc_bits": 2.5}}}, "rig.displacement.adc_bits must be an "
                                                   "integer"),
    ({"rig": [1, 2]}, "rig must be a mapping"),
    ({"other": 1}, "no 'rig' parameters"),
])
def test_bad_rig_files_get_one_line(doc, words):
    with pytest.raises(ParameterError) as err:
        rig_from_mapping(doc, "rig.yaml")
    assert words in str(err.value) and "\n" not in str(err.value)


# --------------------------------------------------------------------------------------
# Through the command line: validate --rig


@pytest.fixture(scope="module")
def recorded(sport_cfg, tmp_path_factory):
    """A 12 Hz, 5 mm sine of the sport damper recorded at 1 kHz through a 2nd-order
    Butterworth load-cell filter at 100 Hz, a 1 ms skew and a 16-bit converter, with 3 N of
    noise; the rig file."""
    import yaml

    from damper_emulator.diagnose.truth import Protocol, simulate_session
    from damper_emulator.dyno.protocols import Chirp, QuasiStatic

    rig = RigParams(force=ForceChannel(filter="butterworth", order=2, cutoff_hz=100.0,
                                       adc_bits=16, full_scale_n=10_000.0, skew_s=1e-3))
    # the sine is the file used; the identification tests as short as the protocol allows
    proto = Protocol(quasi_static=QuasiStatic(amplitude_m=0.005, cycles=1),
                     chirp=Chirp(duration_s=1.0), sines=((12.0, 0.005),))
    data = simulate_session(sport_cfg, proto, 3.0, 5, rig=rig)["sine_12hz.csv"]
    out = tmp_path_factory.mktemp("rig")
    path = write_measured_csv(out / "sine_12hz.csv", data.time, data.displacement,
                              data.force, data.velocity)
    rig_file = out / "rig.yaml"
    rig_file.write_text(yaml.safe_dump(rig_to_mapping(rig)))
    return path, rig_file


def test_validate_through_the_rig_leaves_only_the_noise(cli, recorded, tmp_path):
    """The model that made the recording, validated as if the force were true, is off by
    the chain's delay ``τ`` of the force (filter and skew): to first order ``τ dF/dt``,
    ``τ · rms(dF/dt)`` r.m.s.; through the chain it leaves the noise (3 N; the converter's
    0.09 N; and the force between the 1 kHz samples, which the truth's 4 kHz run filters:
    2.9 N r.m.s. on this sine without noise)."""
    import json

    path, rig_file = recorded
    plain = cli("validate", path, "--params", DEFAULT_PARAMS_FILE, "--json",
                tmp_path / "a.json")
    chained = cli("validate", path, "--params", DEFAULT_PARAMS_FILE, "--rig", rig_file,
                  "--json", tmp_path / "b.json")
    assert plain.returncode == 0 and chained.returncode == 0, plain.stderr + chained.stderr
    a = json.loads((tmp_path / "a.json").read_text())["files"]["sine_12hz.csv"]
    b = json.loads((tmp_path / "b.json").read_text())["files"]["sine_12hz.csv"]
    data = read_measured_csv(path)
    tau = relative_delay(load_rig(rig_file))
    first_order = tau * float(np.sqrt(np.mean(np.gradient(data.force, data.time) ** 2)))
    assert a["rms_N"] == pytest.approx(first_order, rel=0.15)
    assert b["rms_N"] < math.hypot(3.0, 2 * 2.9)
    doc = json.loads((tmp_path / "b.json").read_text())["acquisition"]
    assert doc["source"] == "given" and doc["rig"]["force"]["cutoff_hz"] == 100.0
    assert doc["force_delay_s"] == pytest.approx(math.sqrt(2) / (2 * math.pi * 100) + 1e-3)
    assert json.loads((tmp_path / "a.json").read_text())["acquisition"]["source"] == "none"


def test_validate_refuses_a_bad_rig_file_in_one_line(cli, recorded, tmp_path):
    path, _ = recorded
    bad = tmp_path / "rig.yaml"
    bad.write_text("rig:\n  force:\n    order: 0\n")
    r = cli("validate", path, "--params", DEFAULT_PARAMS_FILE, "--rig", bad, "--json",
            tmp_path / "x.json")
    assert r.returncode == 2
    assert "rig.force.order = 0 must lie in [1, 8]" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.json").exists()

