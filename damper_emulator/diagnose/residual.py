"""Residual analysis: where the model misses a measured record, and what the miss looks like.

:func:`residual_record` simulates a model over a measured record exactly as
:func:`damper_emulator.validation.validate_file` does (the file's time and displacement,
the file's velocity or its Savitzky–Golay derivative) and keeps, per sample, the channels
a residual can be traced to:

* time ``t`` [s], displacement ``x`` [m], velocity ``v`` [m/s],
* acceleration ``a`` [m/s²]: Savitzky–Golay derivative of ``v`` (quadratic, ``deriv=1``,
  ``mode='interp'``) over a window of :data:`ACCEL_WINDOW_S` of physical time (rounded to
  an odd number of samples, at least :data:`ACCEL_MIN_WINDOW`),
* temperature ``T`` [°C] (NaN when the file has none),
* measured force ``F_meas``, model force ``F_model`` [N] and the residual
  ``r = F_meas − F_model`` [N] (note: the opposite sign of validation's ``F_sim − F_meas``;
  here a positive residual is force the model lacks),
* cumulative dissipated energy ``E_i = Σ_{j≤i} ½(F_j + F_{j−1})(x_j − x_{j−1})`` [J]
  (trapezoidal ``∫ F_meas dx``; positive for a damper, force resisting motion, rebound +
  with extension +).

:func:`residual_features` reduces a record to numbers (every formula in its docstring);
:func:`plot_residual` draws one PNG of the residual against each channel and its spectrum.
numpy / scipy / matplotlib only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.acquisition import RigParams
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.model.compressible import DamperModel
from damper_emulator.validation import UNIFORM_DT_TOLERANCE, simulate_record

#: Savitzky–Golay window of the acceleration, in physical time [s]
ACCEL_WINDOW_S = 0.025
#: polynomial order of the acceleration's Savitzky–Golay filter
ACCEL_POLYORDER = 2
#: smallest acceleration window [samples]
ACCEL_MIN_WINDOW = 5
#: quantile bins of the binned-function R² features
N_BINS = 40
#: "near a velocity reversal": |v| ≤ this fraction of the reference speed (99th percentile
#: of |v|)
REVERSAL_FRACTION = 0.05
#: percentile of |v| taken as the reference speed (robust against velocity spikes)
REFERENCE_SPEED_PERCENTILE = 99.0
#: harmonics of the excitation frequency examined by the spectrum features
HARMONICS = (1, 2, 3, 4, 5)
#: half-width of a harmonic's band in FFT bins (the Hann window's main lobe is ±2 bins);
#: never more than half the fundamental, so bands of neighbouring harmonics do not overlap
HARMONIC_HALF_WIDTH_BINS = 2.0
#: A stretch at the start or end of a record with |v| at most the reversal threshold for at
#: least this long is the rig at rest, not a reversal: trimmed before the features [s].
REST_MIN_S = 0.2


@dataclass(frozen=True)
class ResidualRecord:
    """Per-sample channels of one model run on one measured record (SI units, arrays of
    equal length).  ``residual = force_measured − force_model``."""

    time: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    temperature: np.ndarray
    force_measured: np.ndarray
    force_model: np.ndarray
    residual: np.ndarray
    energy: np.ndarray
    name: str = ""
    #: how velocity and acceleration were obtained (velocity_source, filter windows, ...)
    info: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.time.size)

    def sliced(self, start: int, stop: int) -> ResidualRecord:
        """The samples ``start:stop`` (the energy keeps its running value)."""
        arrays = {f: getattr(self, f)[start:stop] for f in
                  ("time", "displacement", "velocity", "acceleration", "temperature",
                   "force_measured", "force_model", "residual", "energy")}
        return ResidualRecord(**arrays, name=self.name, info=dict(self.info))

    @property
    def has_temperature(self) -> bool:
        return bool(np.isfinite(self.temperature).any())


# --------------------------------------------------------------------------------------
# the record


def _uniform(t: np.ndarray) -> tuple[bool, float]:
    dts = np.diff(t)
    dt = float(np.median(dts))
    return bool((dts.max() - dts.min()) <= UNIFORM_DT_TOLERANCE * dt), dt


def acceleration_of(time_s, velocity_m_s) -> tuple[np.ndarray, dict[str, Any]]:
    """Smoothed derivative of the velocity [m/s²] and how it was made.

    Savitzky–Golay (``scipy.signal.savgol_filter``, order :data:`ACCEL_POLYORDER`,
    ``deriv=1``, ``mode='interp'``) over an odd window of ``ACCEL_WINDOW_S / dt`` samples
    (at least :data:`ACCEL_MIN_WINDOW`, at most the record).  Non-uniform sampling is
    resampled on the median interval, differentiated there and interpolated back; fewer
    than :data:`ACCEL_MIN_WINDOW` samples: ``numpy.gradient``.
    """
    from scipy.signal import savgol_filter

    t = np.asarray(time_s, dtype=float)
    v = np.asarray(velocity_m_s, dtype=float)
    n = t.size
    if n < ACCEL_MIN_WINDOW:
        a = np.gradient(v, t) if n > 1 else np.zeros_like(v)
        return a, {"acceleration_source": "gradient"}
    uniform, dt = _uniform(t)
    if uniform:
        tu, vu = t, v
    else:
        m = int(round((t[-1] - t[0]) / dt)) + 1
        tu = np.minimum(t[0] + dt * np.arange(m), t[-1])
        vu = np.interp(tu, t, v)
    w = max(int(round(ACCEL_WINDOW_S / dt)), ACCEL_MIN_WINDOW)
    w += 1 - w % 2
    w = min(w, tu.size if tu.size % 2 else tu.size - 1)
    au = savgol_filter(vu, w, ACCEL_POLYORDER, deriv=1, delta=dt, mode="interp")
    a = au if uniform else np.interp(t, tu, au)
    return a, {"acceleration_source": "savgol", "acceleration_window": int(w),
               "acceleration_window_s": float(w * dt), "acceleration_resampled": not uniform}


def dissipated_energy(displacement_m, force_n) -> np.ndarray:
    """Cumulative ``∫ F dx`` [J], trapezoidal, 0 at the first sample."""
    x = np.asarray(displacement_m, dtype=float)
    f = np.asarray(force_n, dtype=float)
    e = np.zeros_like(x)
    if x.size > 1:
        e[1:] = np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(x))
    return e


def residual_record(model: DamperModel, data: MeasuredData,
                    rig: RigParams | None = None) -> ResidualRecord:
    """Run ``model`` over the measured record ``data`` and keep the per-sample channels.

    The simulation is :func:`~damper_emulator.validation.validate_file`'s: the file's
    time and displacement, its velocity column or, when absent, the Savitzky–Golay
    derivative :func:`~damper_emulator.validation.estimate_velocity`; it starts in
    quasi-steady equilibrium at the first sample. The model's force is recorded through
    the file's measurement chain or, where the file carries none, through ``rig`` (a
    chain estimated by ``diagnose``).

    Raises
    ------
    ValueError
        One line naming the file when the history cannot be simulated.
    """
    t = np.asarray(data.time, dtype=float)
    x = np.asarray(data.displacement, dtype=float)
    f_meas = np.asarray(data.force, dtype=float)
    v, info, res = simulate_record(model, data, rig)
    f_model = res.force_n
    a, how_a = acceleration_of(t, v)
    info.update(how_a)
    temp = (np.asarray(data.temperature, dtype=float) if data.temperature is not None
            else np.full(t.size, math.nan))
    return ResidualRecord(time=t, displacement=x, velocity=v, acceleration=a,
                          temperature=temp, force_measured=f_meas, force_model=f_model,
                          residual=f_meas - f_model, energy=dissipated_energy(x, f_meas),
                          name=data.name, info=info)


# --------------------------------------------------------------------------------------
# features


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if a.size else 0.0


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation; 0 when either has no variance."""
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(np.dot(a, a)) * float(np.dot(b, b)))
    return float(np.dot(a, b) / den) if den > 0 else 0.0


def bin_index(z: np.ndarray, n_bins: int = N_BINS) -> np.ndarray:
    """Quantile-bin index of each sample of ``z``: edges at the ``k/n_bins`` quantiles;
    equal values always share a bin (a constant channel is one bin)."""
    edges = np.quantile(z, np.linspace(0.0, 1.0, n_bins + 1)[1:-1])
    return np.searchsorted(np.unique(edges), z, side="right")


def binned_r2(r: np.ndarray, z: np.ndarray, n_bins: int = N_BINS) -> float:
    """Fraction of the variance of ``r`` explained by a binned (piecewise-constant)
    function of ``z``, adjusted for the number of bins and clipped to [0, 1]:

        R² = 1 − SS_within / SS_total,   SS_within = Σ_bins Σ_i∈bin (r_i − r̄_bin)²
        R²_adj = max(0, 1 − (1 − R²)(N − 1)/(N − k))         (k = bins actually used)

    (so a residual unrelated to ``z`` scores ≈ 0, not ≈ k/N).  0 when ``r`` has no
    variance or ``z`` is constant."""
    n = r.size
    dev = r - r.mean()
    ss_tot = float(np.dot(dev, dev))
    if n < 2 or ss_tot <= 0.0:
        return 0.0
    idx = bin_index(z, n_bins)
    k = int(np.unique(idx).size)
    if k < 2 or n <= k:
        return 0.0
    counts = np.bincount(idx)
    sums = np.bincount(idx, weights=r)
    means = np.divide(sums, counts, out=np.zeros_like(sums), where=counts > 0)
    ss_within = float(np.sum(np.square(r - means[idx])))
    r2 = 1.0 - ss_within / ss_tot
    return float(min(1.0, max(0.0, 1.0 - (1.0 - r2) * (n - 1) / (n - k))))


def binned_means(r: np.ndarray, z: np.ndarray, n_bins: int = N_BINS):
    """``(z̄_bin, r̄_bin)`` of the bins of :func:`bin_index` (for plotting)."""
    idx = bin_index(z, n_bins)
    counts = np.bincount(idx)
    ok = counts > 0
    zb = np.bincount(idx, weights=z)[ok] / counts[ok]
    rb = np.bincount(idx, weights=r)[ok] / counts[ok]
    return zb, rb


def fundamental_frequency(time_s, displacement_m) -> float:
    """Frequency [Hz] of the largest peak of the displacement's amplitude spectrum (mean
    and linear trend removed, median sample interval), ``nan`` for a constant
    displacement."""
    t = np.asarray(time_s, dtype=float)
    x = np.asarray(displacement_m, dtype=float)
    n = t.size
    if n < 4:
        return math.nan
    k = np.arange(n)
    x = x - np.polyval(np.polyfit(k, x, 1), k)
    spec = np.abs(np.fft.rfft(x))
    spec[0] = 0.0
    i = int(np.argmax(spec))
    if not spec[i] > 1e-12 * max(1.0, float(np.abs(x).max()) * n):
        return math.nan
    return float(np.fft.rfftfreq(n, float(np.median(np.diff(t))))[i])


def residual_spectrum(record: ResidualRecord) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectrum ``(f [Hz], P [N²])`` of the whole residual: mean
    removed, Hann window, ``|FFT|²`` (median sample interval; DC bin zeroed)."""
    r = record.residual - record.residual.mean()
    n = r.size
    dt = float(np.median(np.diff(record.time))) if n > 1 else 1.0
    p = np.square(np.abs(np.fft.rfft(r * np.hanning(n))))
    if p.size:
        p[0] = 0.0
    return np.fft.rfftfreq(n, dt), p


def _harmonic_fractions(record: ResidualRecord, f0: float) -> dict[int, float]:
    f, p = residual_spectrum(record)
    total = float(p.sum())
    out = {h: 0.0 for h in HARMONICS}
    if not (math.isfinite(f0) and f0 > 0 and total > 0 and f.size > 1):
        return out
    df = float(f[1] - f[0])
    half = min(HARMONIC_HALF_WIDTH_BINS * df, 0.5 * f0)
    for h in HARMONICS:
        band = (np.abs(f - h * f0) <= half) & (np.rint(f / f0) == h)
        out[h] = float(p[band].sum() / total)
    return out


def trim_rest(record: ResidualRecord, min_rest_s: float = REST_MIN_S
              ) -> tuple[ResidualRecord, float]:
    """``(record, seconds trimmed)``: the record without a leading or trailing stretch at
    rest (``|v| ≤ REVERSAL_FRACTION · P99(|v|)`` for at least ``min_rest_s``): a rig
    standing still before or after a test would otherwise read as a reversal (friction)
    signature and add broadband power.  Interior stretches are kept."""
    n = len(record)
    if n < 2:
        return record, 0.0
    speed = np.abs(record.velocity)
    thr = REVERSAL_FRACTION * float(np.percentile(speed, REFERENCE_SPEED_PERCENTILE))
    moving = np.flatnonzero(speed > thr)
    if moving.size < 2:
        return record, 0.0
    t = record.time
    start = int(moving[0]) if t[moving[0]] - t[0] >= min_rest_s else 0
    stop = int(moving[-1]) + 1 if t[-1] - t[moving[-1]] >= min_rest_s else n
    if start == 0 and stop == n:
        return record, 0.0
    trimmed = float((t[start] - t[0]) + (t[-1] - t[stop - 1]))
    return record.sliced(start, stop), trimmed


def residual_features(record: ResidualRecord) -> dict[str, float]:
    """Numbers that trace the residual ``r = F_meas − F_model`` to an effect.

    Every value is a finite float (an int for ``spectrum_dominant_harmonic``),
    deterministic; only the temperature feature is NaN, and only when the record has no
    temperature.  A leading or trailing stretch at rest is left out first (:func:`trim_rest`,
    ``rest_trimmed_s``).  ``N`` samples; ``corr`` is Pearson's correlation (0 when a side has no
    variance); ``R²_bin(z)`` is :func:`binned_r2` (40 quantile bins, bin-count adjusted).

    Size
        ``rms_N = √mean(r²)``; ``force_rms_N = √mean(F_meas²)``;
        ``relative_rms = rms_N / force_rms_N`` (0 when the force is identically 0);
        ``mean_N = mean(r)``.
    Explained variance
        ``r2_velocity = R²_bin(v)``, ``r2_displacement = R²_bin(x)``,
        ``r2_acceleration = R²_bin(a)``, ``r2_temperature = R²_bin(T)`` (NaN without T).
    Drift
        ``r2_time_linear = corr(r, t)²``, ``r2_energy_linear = corr(r, E)²``
        (``E`` the cumulative dissipated energy); ``drift_N_per_s``: least-squares slope of
        ``r`` against ``t``; ``energy_total_J = E[-1]``.
    Reversals (friction / pre-sliding signature)
        ``v_ref = P99(|v|)``, near a reversal: ``|v| ≤ 0.05 v_ref``
        (``reversal_threshold_m_s``); ``reversal_rms_ratio = rms(r | near) / rms(r | not
        near)`` (0 when the far side's r.m.s. is 0, an empty side has r.m.s. 0);
        ``reversal_fraction``: fraction of samples near a reversal.
    Sign structure
        ``corr_sign_velocity = corr(r, sign v)``, ``corr_velocity = corr(r, v)``.
    Loop quadrants (extension ``v > 0`` / compression ``v ≤ 0`` × accelerating
    ``v·a > 0`` / decelerating ``v·a ≤ 0``)
        ``quadrant_<ext|comp>_<acc|dec>_{mean_N, rms_N, fraction}`` (0 for an empty one).
    Spectrum (:func:`residual_spectrum`: Hann-windowed FFT of the whole residual)
        ``spectrum_fundamental_hz = f0``, the largest peak of the displacement spectrum
        (:func:`fundamental_frequency`; 0 when the displacement is constant);
        ``spectrum_fraction_h<k> = Σ P(f) over |f − k f0| ≤ min(2 Δf, f0/2) / Σ P``
        (k = 1..5); ``spectrum_fraction_harmonics = Σ_k`` of those;
        ``spectrum_fraction_broadband = 1 − spectrum_fraction_harmonics``;
        ``spectrum_dominant_harmonic``: the k with the largest fraction (0 when the
        broadband part exceeds every harmonic's).
    Whiteness
        ``lag1_autocorrelation = Σ (r_i − r̄)(r_{i+1} − r̄) / Σ (r_i − r̄)²`` (0 when r
        has no variance).
    """
    record, rest_s = trim_rest(record)
    r = record.residual
    t, x, v, a = record.time, record.displacement, record.velocity, record.acceleration
    n = r.size
    out: dict[str, Any] = {"samples": int(n), "duration_s": float(t[-1] - t[0]) if n else 0.0,
                           "rest_trimmed_s": rest_s}
    rms = _rms(r)
    f_rms = _rms(record.force_measured)
    out.update(rms_N=rms, force_rms_N=f_rms, relative_rms=rms / f_rms if f_rms > 0 else 0.0,
               mean_N=float(r.mean()) if n else 0.0)
    out["r2_velocity"] = binned_r2(r, v)
    out["r2_displacement"] = binned_r2(r, x)
    out["r2_acceleration"] = binned_r2(r, a)
    out["r2_temperature"] = (binned_r2(r, np.nan_to_num(record.temperature))
                             if record.has_temperature else math.nan)
    out["r2_time_linear"] = _corr(r, t) ** 2
    out["r2_energy_linear"] = _corr(r, record.energy) ** 2
    tc = t - t.mean()
    den = float(np.dot(tc, tc))
    out["drift_N_per_s"] = float(np.dot(tc, r - r.mean()) / den) if den > 0 else 0.0
    out["energy_total_J"] = float(record.energy[-1]) if n else 0.0
    # reversals
    speed = np.abs(v)
    v_ref = float(np.percentile(speed, REFERENCE_SPEED_PERCENTILE)) if n else 0.0
    thr = REVERSAL_FRACTION * v_ref
    near = speed <= thr
    rms_near, rms_far = _rms(r[near]), _rms(r[~near])
    out.update(reversal_threshold_m_s=thr, reversal_fraction=float(near.mean()) if n else 0.0,
               reversal_rms_N=rms_near, nonreversal_rms_N=rms_far,
               reversal_rms_ratio=rms_near / rms_far if rms_far > 0 else 0.0)
    # sign structure
    out["corr_sign_velocity"] = _corr(r, np.sign(v))
    out["corr_velocity"] = _corr(r, v)
    # quadrants
    ext = v > 0
    acc = v * a > 0
    for q_name, mask in (("ext_acc", ext & acc), ("ext_dec", ext & ~acc),
                         ("comp_acc", ~ext & acc), ("comp_dec", ~ext & ~acc)):
        sel = r[mask]
        out[f"quadrant_{q_name}_mean_N"] = float(sel.mean()) if sel.size else 0.0
        out[f"quadrant_{q_name}_rms_N"] = _rms(sel)
        out[f"quadrant_{q_name}_fraction"] = float(mask.mean()) if n else 0.0
    # spectrum
    f0 = fundamental_frequency(t, x)
    fr = _harmonic_fractions(record, f0)
    out["spectrum_fundamental_hz"] = f0 if math.isfinite(f0) else 0.0
    for h in HARMONICS:
        out[f"spectrum_fraction_h{h}"] = fr[h]
    harm = float(sum(fr.values()))
    out["spectrum_fraction_harmonics"] = harm
    out["spectrum_fraction_broadband"] = max(0.0, 1.0 - harm)
    best = max(HARMONICS, key=lambda h: (fr[h], -h))
    out["spectrum_dominant_harmonic"] = (int(best) if fr[best] > 0 and
                                         fr[best] >= out["spectrum_fraction_broadband"]
                                         else 0)
    # whiteness
    dev = r - r.mean()
    ss = float(np.dot(dev, dev))
    out["lag1_autocorrelation"] = (float(np.dot(dev[:-1], dev[1:]) / ss)
                                   if ss > 0 and n > 1 else 0.0)
    return out


# --------------------------------------------------------------------------------------
# figure


def plot_residual(path: str | Path, record: ResidualRecord, title: str | None = None) -> Path:
    """One PNG: the residual ``F_meas − F_model`` against time, velocity, displacement,
    acceleration, temperature (or, without one, the cumulative dissipated energy), each
    scatter with its 40-bin mean (red), and the residual's power spectrum against the
    harmonic number ``f / f0`` with the harmonics marked."""
    from damper_emulator.dyno.plots import DENSE_SAMPLES, new_figure, save

    feats = residual_features(record)
    r = record.residual
    dense = r.size > DENSE_SAMPLES
    ms = 1.0 if dense else 2.0
    # the axes placed by hand: a report draws one of these per file, and matplotlib's
    # constrained layout took two fifths of the report's time
    fig = new_figure(12.0, 10.0, layout=None)
    fig.subplots_adjust(left=0.075, right=0.985, bottom=0.06, top=0.915, hspace=0.42,
                        wspace=0.2)
    axes = fig.subplots(3, 2)
    scatter = dict(linestyle="none", marker=".", markersize=ms, color="C0", alpha=0.35,
                   rasterized=True)
    mean_style = dict(color="C3", linewidth=1.6, label="40-bin mean")

    def panel(ax, z, scale, xlabel, key=None, what=None):
        ax.plot(z * scale, r, **scatter)
        zb, rb = binned_means(r, z)
        ax.plot(zb * scale, rb, **mean_style)
        ax.axhline(0.0, color="0.5", linewidth=0.6)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("residual F_meas − F_model [N]")
        ax.grid(True, alpha=0.35)
        if key is not None:
            ax.set_title(f"{what}: binned R² = {feats[key]:.2f}", fontsize="medium")

    ax = axes[0, 0]
    ax.plot(record.time, r, color="C0", linewidth=0.4 if dense else 0.8)
    ax.axhline(0.0, color="0.5", linewidth=0.6)
    ax.set_xlim(record.time[0], record.time[-1])
    ax.set_xlabel("time [s]")
    ax.set_ylabel("residual F_meas − F_model [N]")
    ax.grid(True, alpha=0.35)
    ax.set_title(f"vs time: linear R² = {feats['r2_time_linear']:.2f}, "
                 f"drift {feats['drift_N_per_s']:.3g} N/s, lag-1 autocorr. "
                 f"{feats['lag1_autocorrelation']:.2f}", fontsize="medium")
    panel(axes[0, 1], record.velocity, 1.0, "velocity [m/s] (extension +)", "r2_velocity",
          "vs velocity")
    axes[0, 1].set_title(
        f"vs velocity: binned R² = {feats['r2_velocity']:.2f}, corr(r, sign v) = "
        f"{feats['corr_sign_velocity']:.2f}, reversal r.m.s. ratio "
        f"{feats['reversal_rms_ratio']:.2f}", fontsize="medium")
    axes[0, 1].legend(loc="best", fontsize="small")
    panel(axes[1, 0], record.displacement, 1e3, "displacement [mm] (extension +)",
          "r2_displacement", "vs displacement")
    panel(axes[1, 1], record.acceleration, 1.0, "acceleration [m/s²] (smoothed dv/dt)",
          "r2_acceleration", "vs acceleration")
    if record.has_temperature:
        panel(axes[2, 0], np.nan_to_num(record.temperature), 1.0, "temperature [°C]",
              "r2_temperature", "vs temperature")
    else:
        panel(axes[2, 0], record.energy, 1.0, "cumulative dissipated energy ∫F dx [J]")
        axes[2, 0].set_title(f"vs energy (no temperature): linear R² = "
                             f"{feats['r2_energy_linear']:.2f}", fontsize="medium")
    ax = axes[2, 1]
    f, p = residual_spectrum(record)
    f0 = feats["spectrum_fundamental_hz"]
    if f.size > 1 and p.max() > 0:
        xs = f / f0 if f0 > 0 else f
        keep = xs <= (10.0 if f0 > 0 else xs[-1])
        ax.semilogy(xs[keep][1:], np.maximum(p[keep][1:], p.max() * 1e-12), color="C0",
                    linewidth=0.9)
        if f0 > 0:
            for h in HARMONICS:
                ax.axvline(h, color="C3", linewidth=0.7, alpha=0.6, linestyle="--")
    ax.set_xlabel(f"harmonic number f / f0 (f0 = {f0:.3g} Hz)" if f0 > 0 else
                  "frequency [Hz]")
    ax.set_ylabel("residual power [N², Hann-windowed FFT]")
    ax.grid(True, alpha=0.35)
    fr = ", ".join(f"h{h} {100 * feats[f'spectrum_fraction_h{h}']:.0f}%" for h in HARMONICS)
    ax.set_title(f"spectrum: {fr}; broadband "
                 f"{100 * feats['spectrum_fraction_broadband']:.0f}%", fontsize="medium")
    name = record.name or "record"
    fig.suptitle(title or f"{name}: residual r.m.s. {feats['rms_N']:.3g} N "
                 f"({100 * feats['relative_rms']:.1f} % of force r.m.s.)")
    return save(fig, path)
