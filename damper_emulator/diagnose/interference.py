"""Narrow-band interference on a recorded channel: found, fitted and left out of the fits.

An unshielded load-cell cable picks up the mains (50 or 60 Hz and its odd harmonics); a
motor drive, a pump or a fan adds a line of its own.  Such a line is the rig's, not the
damper's: a damper driven through a chirp, a random road or a slow triangle has no force
at one fixed frequency whatever the motion, and a damper on a sine puts its force at the
sine's harmonics.  Fitted as an effect, a line becomes a term of the damper that gains
nothing on the held-out files (the mains came back as a ``x²·tanh(ẋ)`` term).

:func:`find_lines` looks for lines in the identified model's residual of every file
(before any effect is scored), :func:`fit_lines` fits each line's amplitude and phase in
every file, and :func:`without_lines` takes them out of the recorded force.

**Finding a line** (per file, :func:`file_peaks`): the periodogram of the residual (linear
trend removed, Hann window) against its running median over
:data:`BACKGROUND_HALF_WIDTH_HZ` either side: a local maximum at least
:data:`PEAK_PROMINENCE` times its background is a peak.  White noise's periodogram is
exponentially distributed (median ``ln 2`` of its mean): a bin exceeds 30 times the median
with probability ``e^(−30 ln 2)`` ≈ 10⁻⁹, so over 10⁵ bins no noise peak passes, while a line
of amplitude ``A`` in noise ``σ`` over ``n`` samples stands about ``n A² / (4 σ²)`` above the
noise's mean (a 3 N line in 4 N of noise over 12 s at 1 kHz: 1,700, less where the
damper's residual is broadband around it).  A peak at a harmonic of a periodic file's
excitation is the damper's force there and is not counted in that file (a 1 Hz sine's
residual has a harmonic at every hertz); nor are those harmonics part of its background,
which bridges them in log power.  Nor does a peak count where the displacement itself has a
line (a multisine's components): the damper answers at the motion's own frequencies.  A
peak must lie :data:`MIN_FIT_CYCLES` of its periods inside the file.

**Stationary** (:func:`find_lines`): a peak is a line when two files show it at the same
frequency (within two of the coarser file's bins), or one file shows it
:data:`LINE_PROMINENCE` times above its background: a swept, random or slow excitation
gives a damper no force at one frequency, and a periodic one only at its harmonics, which
are left out.  Its frequency is then refined where the pooled power of the files that show
it is largest (:func:`_pooled_power`), and its harmonics (up to
:data:`MAX_HARMONIC_SEARCH`) are lines too where one file shows them
:data:`HARMONIC_PROMINENCE` times above their background (the mains' third harmonic is
weaker than the fundamental, and expected with it).

**Fitted and removed** (:func:`fit_lines`, :func:`without_lines`): in every file, by
least squares of ``a cos 2πf_a t + b sin 2πf_a t`` for all lines together on the residual,
``f_a`` the line's alias at the file's sample rate.  A line that aliases to fewer than
:data:`MIN_FIT_CYCLES` cycles over a file (the mains sampled at 50 Hz: a constant) is not
fitted there: it cannot be told from an offset or a slow drift of that file, and says so.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from damper_emulator.dyno.measured import MeasuredData

__all__ = ["Line", "file_peaks", "find_lines", "fit_lines", "without_lines"]

#: a peak stands at least this many times above the running median of the periodogram
PEAK_PROMINENCE = 30.0
#: ... and is a line when two files show it, or one this many times
LINE_PROMINENCE = 100.0
#: a line's harmonics are searched up to this order ...
MAX_HARMONIC_SEARCH = 10
#: ... and count where one file shows them this many times above their background
HARMONIC_PROMINENCE = 20.0
#: half-width of the running median that is a peak's background [Hz] (at least
#: :data:`MIN_BACKGROUND_BINS` bins)
BACKGROUND_HALF_WIDTH_HZ = 2.0
MIN_BACKGROUND_BINS = 8
#: lines are searched from this frequency [Hz] (below it a line is a drift: the series'
#: zero stage's) to this fraction of the sample rate (the anti-alias filter's roll-off)
MIN_LINE_HZ = 1.0
MAX_LINE_FRACTION = 0.45
#: a file's displacement is periodic when its fundamental's harmonics up to
#: :data:`PERIODIC_HARMONICS` explain this fraction of its power (mean and trend removed)
PERIODIC_POWER_FRACTION = 0.9
PERIODIC_HARMONICS = 5
#: a file resolves a line when it spans at least this many of its periods, and a line is
#: fitted in a file where its alias does
MIN_FIT_CYCLES = 4.0
#: two peaks are the same line when they lie within this many bins of the coarser file
SAME_LINE_BINS = 2.0
#: a line this close to 50 or 60 Hz (or an odd multiple of one found) is the mains [Hz]
MAINS_TOLERANCE_HZ = 1.0
MAINS_HZ = (50.0, 60.0)


@dataclass(frozen=True)
class Peak:
    """A peak of one file's residual periodogram."""

    file: str
    frequency_hz: float
    #: its power over the background's (the running median)
    prominence: float
    #: the file's frequency resolution [Hz]
    resolution_hz: float


@dataclass
class Line:
    """A stationary line on the force channel: its frequency, and per file its fitted
    amplitude [N] and phase [rad] (``a cos + b sin`` as amplitude ``√(a²+b²)``)."""

    frequency_hz: float
    #: the files whose residual showed it, with its prominence there
    seen_in: dict[str, float]
    channel: str = "force"
    amplitudes_n: dict[str, float] = field(default_factory=dict)
    phases_rad: dict[str, float] = field(default_factory=dict)
    #: files where it aliases to fewer than MIN_FIT_CYCLES cycles: not fitted, with the
    #: frequency it aliases to
    aliased: dict[str, float] = field(default_factory=dict)
    #: the fundamental this line is an integer multiple of (another line found), if any
    harmonic_of: float | None = None

    @property
    def mains(self) -> bool:
        """Whether it is the mains or one of its harmonics."""
        f0 = self.harmonic_of or self.frequency_hz
        return any(abs(f0 - m) <= MAINS_TOLERANCE_HZ for m in MAINS_HZ)

    @property
    def amplitude_n(self) -> float:
        """Its largest amplitude over the files it was fitted in [N]."""
        return max(self.amplitudes_n.values(), default=0.0)

    def evidence(self) -> str:
        """Why it is the rig's, in words."""
        seen = ", ".join(f"{k} {10 * math.log10(v):.0f} dB" for k, v in self.seen_in.items())
        what = ("the mains" + (f" (harmonic {round(self.frequency_hz / self.harmonic_of)})"
                               if self.harmonic_of else "")
                if self.mains else "a stationary line")
        amps = sorted(self.amplitudes_n.values())
        size = ("" if not amps else f" of {amps[-1]:.3g} N" if len(amps) == 1 or
                amps[0] >= 0.995 * amps[-1] else f" of {amps[0]:.3g}–{amps[-1]:.3g} N")
        out = (f"{what}{size} at {self.frequency_hz:.3f} Hz on the {self.channel} channel, "
               f"above the residual's spectrum around it in {seen}; at one frequency "
               "whatever the excitation, which a damper's force is not; fitted in every "
               "file and left out of the fits")
        if self.aliased:
            out += ("; aliased to " + ", ".join(f"{f:.3g} Hz in {k}" for k, f in
                                                self.aliased.items())
                    + " (too slow to tell from an offset there)")
        return out


def _uniform_rate(t: np.ndarray) -> float | None:
    """The sample rate [Hz] of a uniformly sampled time column, ``None`` otherwise."""
    if t.size < 8:
        return None
    dt = np.diff(t)
    step = float(np.median(dt))
    if not step > 0.0 or float(np.max(np.abs(dt - step))) > 1e-3 * step:
        return None
    return 1.0 / step


def _harmonic_power(t: np.ndarray, y: np.ndarray, f0: float) -> float:
    """The power of ``y`` that harmonics 1 … :data:`PERIODIC_HARMONICS` of ``f0`` [Hz]
    explain, by least squares (no window, no bins: a file of a non-integer number of
    cycles leaks nothing)."""
    tt = t - t[0]
    cols = []
    for h in range(1, PERIODIC_HARMONICS + 1):
        w = 2.0 * math.pi * h * f0 * tt
        cols += [np.cos(w), np.sin(w)]
    a = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    fitted = a @ coef
    return float(np.dot(fitted, fitted))


def _periodic_fundamental(t: np.ndarray, x: np.ndarray) -> float | None:
    """The fundamental [Hz] of a periodic displacement ``x`` (its first
    :data:`PERIODIC_HARMONICS` harmonics explain at least :data:`PERIODIC_POWER_FRACTION`
    of its power, trend removed), else ``None`` (a chirp, a random road).

    Judged where the file moves, from its first crossing of mid-stroke to its last (a
    dyno run starts and ends at rest, which no harmonic explains).  The periodogram's
    largest peak is a start, refined to where the harmonics explain most: the bin's
    frequency is off by up to half a bin, which is ten bins at the twentieth harmonic,
    where a sine's residual still has force."""
    from scipy.optimize import minimize_scalar

    side = x > np.median(x)
    crossings = np.flatnonzero(side[1:] != side[:-1])
    if crossings.size < 2:
        return None
    t, x = t[crossings[0]:crossings[-1] + 2], x[crossings[0]:crossings[-1] + 2]
    n = t.size
    k = np.arange(n)
    y = x - np.polyval(np.polyfit(k, x, 1), k)
    total = float(np.dot(y, y))
    if not total > 0.0:
        return None
    p = np.abs(np.fft.rfft(y * np.hanning(n))) ** 2
    p[0] = 0.0
    i = int(np.argmax(p))
    if i == 0:
        return None
    df = 1.0 / (n * float(np.median(np.diff(t))))
    res = minimize_scalar(lambda f: -_harmonic_power(t, y, f),
                          bounds=((i - 1) * df, (i + 1) * df), method="bounded",
                          options={"xatol": 1e-6 * df})
    f0 = float(res.x) if res.success else i * df
    if not f0 > 0.0 or _harmonic_power(t, y, f0) < PERIODIC_POWER_FRACTION * total:
        return None
    return f0


def _spectrum(t: np.ndarray, residual: np.ndarray, x: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """``(f, ratio, counted)`` of one file's residual (module docstring): the frequencies
    [Hz], the periodogram over its running median, and where a peak may count (inside the
    band, clear of a periodic excitation's harmonics); ``None`` for a file sampled
    unevenly."""
    from scipy.ndimage import median_filter

    fs = _uniform_rate(t)
    if fs is None:
        return None
    n = t.size
    k = np.arange(n)
    r = residual - np.polyval(np.polyfit(k, residual, 1), k)
    p = np.abs(np.fft.rfft(r * np.hanning(n))) ** 2
    f = np.fft.rfftfreq(n, 1.0 / fs)
    df = float(f[1])
    counted = ((f >= max(MIN_LINE_HZ, MIN_FIT_CYCLES / (t[-1] - t[0])))
               & (f <= MAX_LINE_FRACTION * fs))
    half = max(MIN_BACKGROUND_BINS, math.ceil(BACKGROUND_HALF_WIDTH_HZ / df))
    f0 = _periodic_fundamental(t, x)
    if f0 is None:
        bg = median_filter(p, size=2 * half + 1, mode="nearest")
    else:
        # the excitation's harmonics are the damper's: no peak there, and no part of the
        # background either, which is the running median of the bins clear of them (as
        # many as the window would hold, at their share of the spectrum), bridged across
        # the harmonics in log power.  The Hann window's main lobe is two bins either side
        # of a harmonic, which lies anywhere within half a bin of the bin nearest it.
        h = np.rint(f / f0)
        harmonic = (h >= 1) & (np.abs(f - h * f0) <= (SAME_LINE_BINS + 0.5) * df)
        counted &= ~harmonic
        clear = np.flatnonzero(~harmonic & (p > 0))
        if clear.size < 2:
            return None
        half_clear = max(MIN_BACKGROUND_BINS // 2,
                         math.ceil(half * clear.size / p.size))
        bg_clear = median_filter(p[clear], size=2 * half_clear + 1, mode="nearest")
        bg = np.exp(np.interp(np.arange(p.size), clear, np.log(bg_clear)))
    ratio = p / np.maximum(bg, np.finfo(float).tiny)
    # where the motion itself has a line (a multisine's components, a slider-crank's
    # harmonics), the damper answers with one: not interference
    y = x - np.polyval(np.polyfit(k, x, 1), k)
    px = np.abs(np.fft.rfft(y * np.hanning(n))) ** 2
    moving = px / np.maximum(median_filter(px, size=2 * half + 1, mode="nearest"),
                             np.finfo(float).tiny) >= PEAK_PROMINENCE
    near = int(math.ceil(SAME_LINE_BINS))
    for sh in range(-near, near + 1):
        counted &= ~np.roll(moving, sh)
    return f, ratio, counted


def file_peaks(name: str, t: np.ndarray, residual: np.ndarray, x: np.ndarray
               ) -> list[Peak]:
    """The peaks of one file's residual periodogram (module docstring)."""
    spec = _spectrum(t, residual, x)
    if spec is None:
        return []
    f, ratio, counted = spec
    local_max = np.ones(f.size, dtype=bool)
    for s in (1, 2):
        local_max[s:] &= ratio[s:] >= ratio[:-s]
        local_max[:-s] &= ratio[:-s] >= ratio[s:]
    ok = local_max & counted & (ratio >= PEAK_PROMINENCE)
    return [Peak(name, float(f[i]), float(ratio[i]), float(f[1])) for i in np.flatnonzero(ok)]


def _prominence_at(freq: float, t: np.ndarray, residual: np.ndarray, x: np.ndarray
                   ) -> float | None:
    """One file's largest prominence within two bins of ``freq`` where a peak may count
    there, else ``None``."""
    spec = _spectrum(t, residual, x)
    if spec is None:
        return None
    f, ratio, counted = spec
    near = np.flatnonzero(np.abs(f - freq) <= SAME_LINE_BINS * f[1])
    near = near[counted[near]]
    return float(ratio[near].max()) if near.size else None


def _alias(f: float, fs: float) -> float:
    """The frequency ``f`` [Hz] sampled at ``fs`` appears at (0 … fs/2)."""
    return abs(f - fs * round(f / fs))


def _design(t: np.ndarray, freqs: Sequence[float]) -> np.ndarray:
    """Columns ``cos 2πft, sin 2πft`` for each of ``freqs``, time from the file's start."""
    tt = t - t[0]
    cols = []
    for f in freqs:
        w = 2.0 * math.pi * f * tt
        cols += [np.cos(w), np.sin(w)]
    return np.column_stack(cols) if cols else np.zeros((t.size, 0))


def _pooled_power(f: float, series: Sequence[tuple[np.ndarray, np.ndarray]]) -> float:
    """Σ over files of the least-squares power of a sinusoid at ``f`` in the residual."""
    total = 0.0
    for t, r in series:
        a = _design(t, [f])
        coef, *_ = np.linalg.lstsq(a, r - r.mean(), rcond=None)
        total += float(np.dot(coef, coef)) * t.size
    return total


def _refined(f: float, width: float, series: Sequence[tuple[np.ndarray, np.ndarray]]
             ) -> float:
    """The frequency within ``f ± width`` where :func:`_pooled_power` is largest."""
    from scipy.optimize import minimize_scalar

    res = minimize_scalar(lambda g: -_pooled_power(g, series), bounds=(f - width, f + width),
                          method="bounded", options={"xatol": 1e-4 * width})
    return float(res.x) if res.success else f


def find_lines(files: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> list[Line]:
    """The stationary lines in the residuals ``{file: (t, residual, displacement)}``
    (module docstring), lowest frequency first, each harmonic with its fundamental."""
    peaks = [p for name, (t, r, x) in files.items() for p in file_peaks(name, t, r, x)]
    peaks.sort(key=lambda p: p.frequency_hz)
    groups: list[list[Peak]] = []
    for p in peaks:
        g = groups[-1] if groups else None
        if g is not None and abs(p.frequency_hz - g[-1].frequency_hz) <= SAME_LINE_BINS * max(
                p.resolution_hz, g[-1].resolution_hz) and p.file not in {q.file for q in g}:
            g.append(p)
        else:
            groups.append([p])
    lines: list[Line] = []
    for g in groups:
        best = max(g, key=lambda q: q.prominence)
        if len(g) < 2 and best.prominence < LINE_PROMINENCE:
            continue
        series = [(files[q.file][0], files[q.file][1]) for q in g]
        f = _refined(best.frequency_hz, best.resolution_hz, series)
        lines.append(Line(f, {q.file: q.prominence for q in g}))
    for fundamental in list(lines):
        if fundamental.harmonic_of is not None:
            continue
        for k in range(2, MAX_HARMONIC_SEARCH + 1):
            fk = k * fundamental.frequency_hz
            known = [ln for ln in lines if abs(ln.frequency_hz - fk) <= MAINS_TOLERANCE_HZ]
            if known:
                known[0].harmonic_of = fundamental.frequency_hz
                continue
            seen = {}
            for name, (t, r, x) in files.items():
                prominence = _prominence_at(fk, t, r, x)
                if prominence is not None and prominence >= HARMONIC_PROMINENCE:
                    seen[name] = prominence
            if seen:
                lines.append(Line(fk, seen, harmonic_of=fundamental.frequency_hz))
    return sorted(lines, key=lambda ln: ln.frequency_hz)


def fit_lines(lines: Sequence[Line], files: Mapping[str, tuple[np.ndarray, np.ndarray]]
              ) -> dict[str, np.ndarray]:
    """Fit every line in every file of ``{file: (t, residual)}`` (their amplitudes and
    phases filled in, or the file noted under ``aliased``); the fitted lines' sum per
    file, at its sample times [N]."""
    out = {}
    for name, (t, r) in files.items():
        fs = _uniform_rate(t) or 1.0 / float(np.median(np.diff(t)))
        span = float(t[-1] - t[0])
        fitted = []
        for line in lines:
            fa = _alias(line.frequency_hz, fs)
            if fa * span < MIN_FIT_CYCLES:
                line.aliased[name] = fa
            else:
                fitted.append((line, fa))
        a = _design(t, [fa for _, fa in fitted])
        if not fitted:
            out[name] = np.zeros_like(r)
            continue
        design = np.column_stack([a, np.ones_like(t)])
        coef, *_ = np.linalg.lstsq(design, r, rcond=None)
        for k, (line, _) in enumerate(fitted):
            c, s = coef[2 * k], coef[2 * k + 1]
            line.amplitudes_n[name] = float(math.hypot(c, s))
            line.phases_rad[name] = float(math.atan2(-s, c))
        out[name] = a @ coef[:-1]
    return out


def without_lines(data: MeasuredData, fitted: np.ndarray) -> MeasuredData:
    """``data`` with the fitted lines taken out of its force."""
    return replace(data, force=data.force - fitted)
