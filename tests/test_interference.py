"""Narrow-band interference on the force channel (damper_emulator.diagnose.interference):
lines found where the excitation cannot put them, fitted and taken out; a damper's own
force (swept, or at a sine's harmonics) is never taken for one."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from damper_emulator.diagnose.interference import (
    MIN_FIT_CYCLES,
    find_lines,
    fit_lines,
    without_lines,
)
from damper_emulator.dyno.measured import MeasuredData

FS = 1000.0
NOISE_N = 4.0


def chirp_file(rng, duration=12.0, lines=(), fs=FS):
    """A swept excitation's residual: the damper's miss at the sweep's first harmonics
    (broadband over the file), white noise, and ``lines`` ``(f, amplitude, phase)``."""
    t = np.arange(int(duration * fs)) / fs
    phase = 2 * math.pi * (0.5 * t + (16.0 - 0.5) / (2 * duration) * t ** 2)
    x = 0.016 * np.sin(phase)
    r = 20.0 * np.sin(phase + 0.3) + 8.0 * np.sin(3 * phase) + rng.normal(0, NOISE_N, t.size)
    for f, a, phi in lines:
        r += a * np.sin(2 * math.pi * f * t + phi)
    return t, r, x


def sine_file(rng, f0=1.0, duration=3.0, lines=(), fs=FS, harmonics=80, rest=0.0):
    """A sine's residual: the damper's miss at every harmonic of the sine up to
    ``harmonics`` (a friction switch's 1/k), white noise, and ``lines``; the last ``rest``
    seconds at rest (the sine held where it stopped, nothing but noise and lines)."""
    t = np.arange(int((duration + rest) * fs)) / fs
    moving = t < duration
    tm = np.where(moving, t, duration)
    x = 0.05 * np.sin(2 * math.pi * f0 * tm)
    r = rng.normal(0, NOISE_N, t.size)
    for k in range(1, harmonics + 1):
        if k * f0 < 0.45 * fs:
            r += moving * 30.0 / k * np.sin(2 * math.pi * k * f0 * t + 0.1 * k)
    for f, a, phi in lines:
        r += a * np.sin(2 * math.pi * f * t + phi)
    return t, r, x


MAINS = ((50.0, 3.0, 0.4), (150.0, 1.0, 1.9))


def test_the_mains_and_its_third_harmonic_are_found_and_fitted_in_every_file():
    rng = np.random.default_rng(1)
    files = {"chirp.csv": chirp_file(rng, lines=MAINS),
             "sine_1hz.csv": sine_file(rng, 1.0, lines=MAINS),
             "sine_3hz.csv": sine_file(rng, 3.0, duration=1.0, lines=MAINS)}
    lines = find_lines(files)
    assert [round(ln.frequency_hz) for ln in lines] == [50, 150]
    fifty, third = lines
    assert fifty.frequency_hz == pytest.approx(50.0, abs=0.02)
    assert third.harmonic_of == pytest.approx(fifty.frequency_hz)
    assert fifty.mains and third.mains
    fit_lines(lines, {n: (t, r) for n, (t, r, _) in files.items()})
    for name, (t, _, _) in files.items():
        # least squares of a sinusoid in white noise: σ_A = σ √(2/n)
        tol = 4.0 * NOISE_N * math.sqrt(2.0 / t.size) + 0.05
        assert fifty.amplitudes_n[name] == pytest.approx(3.0, abs=tol), name
        assert third.amplitudes_n[name] == pytest.approx(1.0, abs=tol), name
    assert "mains" in fifty.evidence() and "50.0" in fifty.evidence()
    # the evidence states the size fitted, which the truth's 3 N must fall in
    lo, hi = re.search(r"of ([\d.]+)–([\d.]+) N", fifty.evidence()).groups()
    assert float(lo) - tol <= 3.0 <= float(hi) + tol


@pytest.mark.parametrize("seed", range(5))
def test_a_damper_residual_without_a_line_gives_none(seed):
    """Swept harmonics, a sine's 80 harmonics (one at every hertz, 50 Hz among them) and
    noise over five seeds: nothing at 100 times its background that two files share."""
    rng = np.random.default_rng(seed)
    files = {"chirp.csv": chirp_file(rng), "sine_1hz.csv": sine_file(rng, 1.0),
             "sine_3hz.csv": sine_file(rng, 3.0, duration=1.0),
             "sine_12hz.csv": sine_file(rng, 12.0, duration=0.25)}
    assert find_lines(files) == []


def test_a_dyno_runs_harmonics_off_its_bins_and_its_rest_give_no_line():
    """A crank dyno's sine is no whole number of cycles nor of bins: 9.5 cycles then rest
    (a short run), 101.3 cycles (a long one), at 300 Hz, the residual's harmonics up to
    the 40th.  The fundamental off its bin by up to half a bin is 20 bins off at the
    40th harmonic; found to a fraction of a bin, every harmonic is the damper's."""
    rng = np.random.default_rng(11)
    f0 = 1.05295
    files = {"short.csv": sine_file(rng, f0, duration=9.5 / f0, fs=300.0, harmonics=40,
                                    rest=0.8),
             "long.csv": sine_file(rng, f0, duration=101.3 / f0, fs=300.0, harmonics=40)}
    assert find_lines(files) == []
    pump = ((37.3, 2.0, 0.0),)  # ... while a line between two harmonics still is one
    files["long.csv"] = sine_file(rng, f0, duration=101.3 / f0, fs=300.0, harmonics=40,
                                  lines=pump)
    (line,) = find_lines(files)
    assert line.frequency_hz == pytest.approx(37.3, abs=0.01)


def test_a_line_at_another_frequency_is_found_and_not_called_the_mains():
    rng = np.random.default_rng(2)
    pump = ((37.3, 2.0, 0.0),)
    files = {"chirp.csv": chirp_file(rng, lines=pump),
             "sine_3hz.csv": sine_file(rng, 3.0, duration=2.0, lines=pump)}
    (line,) = find_lines(files)
    assert line.frequency_hz == pytest.approx(37.3, abs=0.02)
    assert not line.mains and "stationary line" in line.evidence()


def test_a_file_that_aliases_the_line_to_an_offset_is_not_fitted_and_says_so():
    """The quasi-static test sampled at 50 Hz sees the mains at 0 Hz: a constant, which
    only the zero of that file can take."""
    rng = np.random.default_rng(3)
    files = {"chirp.csv": chirp_file(rng, lines=MAINS),
             "sine_1hz.csv": sine_file(rng, 1.0, lines=MAINS)}
    lines = find_lines(files)
    slow_t = np.arange(0, 150.0, 1 / 50.0)
    series = {n: (t, r) for n, (t, r, _) in files.items()}
    series["quasi_static.csv"] = (slow_t, rng.normal(0, NOISE_N, slow_t.size) + 2.0)
    fitted = fit_lines(lines, series)
    for line in lines:
        assert line.aliased["quasi_static.csv"] * 150.0 < MIN_FIT_CYCLES
        assert "quasi_static.csv" not in line.amplitudes_n
    assert np.all(fitted["quasi_static.csv"] == 0.0)
    assert "aliased to" in lines[0].evidence()


def test_taking_the_lines_out_leaves_the_force_without_them():
    """The cleaned force against the same record made without the lines: what is left of
    them is the least-squares error of two sinusoids in the noise (``σ √(2/n)`` each)."""
    rng = np.random.default_rng(4)
    t, r_clean, x = chirp_file(rng)
    hum = sum(a * np.sin(2 * math.pi * f * t + phi) for f, a, phi in MAINS)
    other = sine_file(rng, 1.0, lines=MAINS)
    files = {"chirp.csv": (t, r_clean + hum, x), "sine_1hz.csv": other}
    lines = find_lines(files)
    fitted = fit_lines(lines, {n: (tt, rr) for n, (tt, rr, _) in files.items()})
    data = MeasuredData(time=t, displacement=x, force=r_clean + hum, name="chirp.csv")
    left = without_lines(data, fitted["chirp.csv"]).force - r_clean
    assert np.sqrt(np.mean(left ** 2)) < 3.0 * NOISE_N * math.sqrt(2.0 * len(MAINS) / t.size)


def multisine_file(rng, lines=(), duration=20.0, fs=FS):
    """A random road replayed as a multisine (200 components of one velocity amplitude,
    1–15 Hz, as truth.RandomDrive): an inertia's residual ``m ẍ`` is a line at every
    component, largest at the band's top, where the spectrum above is the noise's."""
    t = np.arange(int(duration * fs)) / fs
    f = np.geomspace(1.0, 15.0, 200)
    phase = rng.uniform(0, 2 * np.pi, f.size)
    arg = 2 * np.pi * np.outer(t, f) + phase
    x = (0.25 / (2 * np.pi * 10.0) / f * np.sin(arg)).sum(axis=1)
    r = (5.0 * 0.25 / 10.0 * 2 * np.pi * f * -np.sin(arg)).sum(axis=1)  # 5 kg · ẍ
    r += rng.normal(0, NOISE_N, t.size)
    for fl, a, phi in lines:
        r += a * np.sin(2 * math.pi * fl * t + phi)
    return t, r, x


def test_the_damper_answering_a_multisine_at_its_own_frequencies_is_no_line():
    """The residual's lines at the motion's own components are the damper's; the mains
    beside them is a line, found in that one file."""
    rng = np.random.default_rng(5)
    assert find_lines({"road.csv": multisine_file(rng)}) == []
    (line, third) = find_lines({"road.csv": multisine_file(rng, lines=((50.0, 4.0, 0.3),
                                                                       (150.0, 2.0, 0.0)))})
    assert line.frequency_hz == pytest.approx(50.0, abs=0.02) and line.mains
    assert third.harmonic_of == pytest.approx(line.frequency_hz)
