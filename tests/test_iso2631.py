"""ISO 2631-1 weightings (analogue and digital) and the clause 6 vibration metrics."""

import math

import numpy as np
import pytest
from scipy import signal

from damper_emulator.errors import UserError
from ride_sim import iso2631, metrics

# --------------------------------------------------------------------------------------------
# Independent reference: ISO 2631-1:1997 Annex A written out in scalar complex arithmetic,
# with the Table A.2 constants typed here, not imported from the module under test.
# --------------------------------------------------------------------------------------------
_TABLE_A2 = {
    #      f1    f2     f3    f4    Q4    (f5, Q5, f6, Q6) or None
    "Wk": (0.4, 100.0, 12.5, 12.5, 0.63, (2.37, 0.91, 3.35, 0.91)),
    "Wd": (0.4, 100.0, 2.0, 2.0, 0.63, None),
}


def _reference(name: str, f: float) -> complex:
    f1, f2, f3, f4, q4, step = _TABLE_A2[name]
    p = 2j * math.pi * f
    w1, w2, w3, w4 = (2 * math.pi * fi for fi in (f1, f2, f3, f4))
    hh = 1 / (1 + math.sqrt(2) * w1 / p + (w1 / p) ** 2)
    hl = 1 / (1 + math.sqrt(2) * p / w2 + (p / w2) ** 2)
    ht = (1 + p / w3) / (1 + p / (q4 * w4) + (p / w4) ** 2)
    hs = 1.0
    if step is not None:
        f5, q5, f6, q6 = step
        w5, w6 = 2 * math.pi * f5, 2 * math.pi * f6
        hs = ((w5 / w6) ** 2 * (1 + p / (q5 * w5) + (p / w5) ** 2)
              / (1 + p / (q6 * w6) + (p / w6) ** 2))
    return hh * hl * ht * hs


# ISO 2631-1:1997 Table 3, weighting factors x 1000 at the nominal one-third-octave centre
# frequencies, printed to three significant figures (one decimal below 100).  Annex A at the
# nominal frequency reproduces every entry within one unit of the last printed digit (the
# largest gap, 0.7, is Wk at 16 Hz; all others are within rounding).
_TABLE_3 = {
    "Wk": {0.5: 418, 1.0: 482, 2.0: 531, 4.0: 967, 5.0: 1039, 6.3: 1054, 8.0: 1036, 10.0: 988,
           12.5: 902, 16.0: 768, 31.5: 405, 63.0: 186, 80.0: 132},
    "Wd": {0.5: 853, 1.0: 1011, 2.0: 890, 4.0: 512, 8.0: 253, 16.0: 125, 31.5: 63.2,
           63.0: 29.5, 80.0: 21.1},
}


def _amplitude(y: np.ndarray, f: float, fs: float) -> float:
    """Amplitude of the component of ``y`` at ``f`` (least squares on sin and cos)."""
    t = np.arange(y.size) / fs
    basis = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
    coeffs, *_ = np.linalg.lstsq(basis, y, rcond=None)
    return float(np.hypot(*coeffs))


# ------------------------------------------------------------------------- analogue weighting
@pytest.mark.parametrize("name", ["Wk", "Wd"])
@pytest.mark.parametrize("f", [0.7, 1.0, 3.0, 5.0, 8.0, 16.0, 31.5, 63.0, 79.0])
def test_frequency_weighting_matches_annex_a(name, f):
    assert complex(iso2631.frequency_weighting(name, f)) == pytest.approx(_reference(name, f),
                                                                         rel=1e-12)


@pytest.mark.parametrize(("name", "f", "factor"),
                         [(n, f, v) for n, table in _TABLE_3.items() for f, v in table.items()])
def test_frequency_weighting_matches_table_3(name, f, factor):
    unit = 1.0 if factor >= 100 else 0.1                  # one unit of the last printed digit
    assert abs(abs(iso2631.frequency_weighting(name, f)) * 1000 - factor) <= unit


def test_frequency_weighting_array_scalar_dc_and_symmetry():
    f = np.array([[0.0, 1.0], [5.0, 50.0]])
    h = iso2631.frequency_weighting("Wk", f)
    assert h.shape == f.shape and h.dtype == np.complex128
    assert h[0, 0] == 0                                            # high-pass: no response at DC
    assert isinstance(iso2631.frequency_weighting("Wd", 2.0), complex)
    assert iso2631.frequency_weighting("Wk", -5.0) == pytest.approx(
        np.conj(iso2631.frequency_weighting("Wk", 5.0)))


def test_unknown_weighting_names_the_known_ones():
    with pytest.raises(ValueError, match="unknown weighting 'Wz'; known: Wd, Wk"):
        iso2631.frequency_weighting("Wz", 1.0)
    with pytest.raises(ValueError, match="known: Wd, Wk"):
        iso2631.weight_signal("wk", np.zeros(10), 1000.0)
    with pytest.raises(ValueError, match="finite"):
        iso2631.frequency_weighting("Wk", [1.0, np.nan])


# -------------------------------------------------------------------------- digital filter
@pytest.mark.parametrize("name", ["Wk", "Wd"])
@pytest.mark.parametrize("fs", [100.0, 200.0, 256.0, 500.0, 1000.0, 2000.0, 4096.0])
def test_digital_magnitude_within_one_percent_over_the_accuracy_band(name, fs):
    f_low, f_high = iso2631.accuracy_band(fs)
    assert (f_low, f_high) == (0.5, min(80.0, fs / 4))
    f = np.geomspace(f_low, f_high, 1500)
    _, h = signal.sosfreqz(iso2631.weighting_sos(name, fs), worN=f, fs=fs)
    reference = np.array([abs(_reference(name, fi)) for fi in f])
    error = np.max(np.abs(np.abs(h) / reference - 1))
    assert error < 0.01
    if fs >= 500.0:                                     # the documented margin at these rates
        assert error < 1e-4


@pytest.mark.parametrize("name", ["Wk", "Wd"])
def test_weighted_sines_have_the_analogue_gain(name):
    fs = 1000.0
    settle_s, measure_s = 8.0, 8.0                  # 0.4 Hz high-pass: transient < 1e-6 at 8 s
    t = np.arange(round((settle_s + measure_s) * fs)) / fs
    for f in [0.5, 1.0, 2.5, 5.0, 8.0, 12.5, 20.0, 31.5, 50.0, 80.0]:
        y = iso2631.weight_signal(name, 0.7 * np.sin(2 * np.pi * f * t + 0.3), fs)
        gain = _amplitude(y[round(settle_s * fs):], f, fs) / 0.7
        assert gain == pytest.approx(abs(_reference(name, f)), rel=0.01), f


def test_streaming_filter_equals_batch_and_resets():
    fs = 500.0
    x = np.random.default_rng(1).standard_normal(5000)
    batch = iso2631.weight_signal("Wk", x, fs)
    filt = iso2631.WeightingFilter("Wk", fs)
    cuts = np.sort(np.random.default_rng(2).choice(np.arange(1, x.size), 20, replace=False))
    streamed = np.concatenate([filt.process(chunk) for chunk in np.split(x, cuts)])
    np.testing.assert_allclose(streamed, batch, rtol=0, atol=1e-12)
    assert filt.process([]).size == 0
    filt.reset()
    np.testing.assert_allclose(filt.process(x[:100]), batch[:100], rtol=0, atol=1e-12)
    assert filt.band_hz == (0.5, 80.0) and filt.max_magnitude_error < 1e-4
    np.testing.assert_array_equal(filt.sos, iso2631.weighting_sos("Wk", fs))


def test_static_offset_is_rejected():
    fs = 1000.0
    gravity = np.full(round(20 * fs), 9.81)
    from_rest = iso2631.weight_signal("Wk", gravity, fs)
    assert np.max(np.abs(from_rest[-round(fs):])) < 1e-9          # start transient has decayed
    steady = iso2631.weight_signal("Wk", gravity, fs, start="steady")
    assert np.max(np.abs(steady)) < 1e-9                          # and with a steady start: none


def test_digital_filter_rejects_bad_input():
    with pytest.raises(ValueError, match=r"below the minimum 100\.0 Hz"):
        iso2631.weight_signal("Wk", np.zeros(10), 50.0)
    with pytest.raises(ValueError, match="finite and positive"):
        iso2631.WeightingFilter("Wd", float("nan"))
    with pytest.raises(ValueError, match="1-D"):
        iso2631.weight_signal("Wk", np.zeros((2, 10)), 1000.0)
    with pytest.raises(ValueError, match="finite"):
        iso2631.weight_signal("Wk", [0.0, np.inf], 1000.0)
    with pytest.raises(ValueError, match="start"):
        iso2631.weight_signal("Wk", np.zeros(10), 1000.0, start="warm")


def test_constants_tables_are_frozen_and_validated():
    with pytest.raises(AttributeError):
        iso2631.WK.transition_q = 0.7
    with pytest.raises(ValueError, match="transition_q"):
        iso2631.WeightingConstants("Wx", 0.4, 100.0, 2.0, 2.0, -0.63)
    assert iso2631.WD.upward_step is None and iso2631.WK.upward_step.pole_hz == 3.35


# --------------------------------------------------------------------------------- metrics
FS = 1000.0


def _sine(amplitude: float, f: float, duration_s: float) -> np.ndarray:
    return amplitude * np.sin(2 * np.pi * f * np.arange(round(duration_s * FS)) / FS)


def test_rms_and_peaks_of_a_sine():
    x = _sine(1.7, 5.0, 4.0)                            # whole cycles, a sample on each crest
    assert metrics.rms(x) == pytest.approx(1.7 / math.sqrt(2), rel=1e-12)
    assert metrics.peaks(x) == pytest.approx((1.7, -1.7), rel=1e-12)
    assert metrics.peaks([3.0, -1.0, 2.0]) == (3.0, -1.0)
    assert metrics.crest_factor(x) == pytest.approx(math.sqrt(2), rel=1e-12)


def test_vdv_of_a_sine_has_the_closed_form():
    amplitude, duration = 2.3, 10.0                     # ∫ sin⁴ over whole cycles = 3T/8
    x = _sine(amplitude, 5.0, duration)
    assert metrics.vdv(x, FS) == pytest.approx(amplitude * (3 * duration / 8) ** 0.25, rel=1e-12)


def test_mtvv_of_bursts():
    amplitude = 3.0
    quiet = np.zeros(round(5 * FS))
    long_burst = np.concatenate([quiet, _sine(amplitude, 5.0, 2.0), quiet])
    assert metrics.mtvv(long_burst, FS) == pytest.approx(amplitude / math.sqrt(2), rel=1e-9)
    # a burst of 0.4 s, shorter than τ = 1 s: its energy is spread over the whole window
    short_burst = np.concatenate([quiet, _sine(amplitude, 5.0, 0.4), quiet])
    assert metrics.mtvv(short_burst, FS) == pytest.approx(
        amplitude / math.sqrt(2) * math.sqrt(0.4 / 1.0), rel=1e-9)
    # exponential averaging settles on the r.m.s. of a steady sine (ripple ~0.2 % at 40 Hz)
    steady = _sine(amplitude, 40.0, 10.0)
    assert metrics.mtvv(steady, FS, averaging="exponential") == pytest.approx(
        amplitude / math.sqrt(2), rel=5e-3)


def test_running_rms_matches_its_definition():
    x = np.random.default_rng(3).standard_normal(3000)
    a = metrics.running_rms(x, FS)
    n = round(FS * 1.0)
    for i in [0, 10, 999, 1000, 2999]:
        window = x[max(0, i - n + 1):i + 1]                      # zero before the first sample
        assert a[i] == pytest.approx(math.sqrt(np.sum(window**2) / n), rel=1e-9)
    assert a.shape == x.shape
    b = metrics.running_rms(x, FS, integration_time_s=0.125, averaging="exponential")
    alpha = math.exp(-1 / (0.125 * FS))
    m = 0.0
    for value in x[:50]:
        m = alpha * m + (1 - alpha) * value**2
    assert b[49] == pytest.approx(math.sqrt(m), rel=1e-12)


@pytest.mark.parametrize(("bad", "why"), [([], "must not be empty"),
                                          ([[1.0, 2.0]], "must be 1-D"),
                                          ([1.0, np.nan], "must be finite"),
                                          ([np.inf], "must be finite")])
def test_metrics_reject_bad_signals(bad, why):
    for call in (metrics.rms, metrics.peaks, metrics.crest_factor,
                 lambda x: metrics.vdv(x, FS), lambda x: metrics.mtvv(x, FS)):
        with pytest.raises(UserError, match=f"signal {why}"):
            call(bad)


def test_metrics_reject_bad_parameters():
    x = np.ones(100)
    for fs in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="sampling rate"):
            metrics.vdv(x, fs)
        with pytest.raises(ValueError, match="sampling rate"):
            metrics.running_rms(x, fs)
    with pytest.raises(ValueError, match="integration time"):
        metrics.running_rms(x, FS, integration_time_s=0.0)
    with pytest.raises(ValueError, match="averaging"):
        metrics.mtvv(x, FS, averaging="peak")
    with pytest.raises(ValueError, match="all-zero"):
        metrics.crest_factor(np.zeros(5))
