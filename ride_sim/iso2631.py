"""ISO 2631-1 frequency weightings for whole-body vibration, analogue and digital.

The analogue weightings follow ISO 2631-1:1997 Annex A: each weighting is the product of a
band limitation (a second-order Butterworth high-pass ``Hh`` at ``f1`` and low-pass ``Hl`` at
``f2``), an acceleration-velocity transition ``Ht`` and, for ``Wk``, an upward step ``Hs``.
With ``p = j 2π f`` and ``ωi = 2π fi``::

    Hh = 1 / (1 + √2 ω1/p + (ω1/p)²)
    Hl = 1 / (1 + √2 p/ω2 + (p/ω2)²)
    Ht = (1 + p/ω3) / (1 + p/(Q4 ω4) + (p/ω4)²)
    Hs = (ω5/ω6)² (1 + p/(Q5 ω5) + (p/ω5)²) / (1 + p/(Q6 ω6) + (p/ω6)²)

``Hs`` tends to ``(ω5/ω6)² ≈ 0.5`` at low frequency and to 1 above ``f6``, which reproduces the
weighting factors of the standard's Table 3 (``Wk`` 0.482 at 1 Hz, 1.054 at 6.3 Hz).

Only ``Wk`` (vertical, z axis) and ``Wd`` (horizontal, x and y axes) are provided: they are the
two the ride simulation reports, and their Table A.2 constants are checked in the tests against
the standard's tabulated weighting factors.

Digital filter
--------------
A bilinear transform bends the frequency axis: over 0.5–80 Hz it misses the analogue
magnitude by up to 3.4 % at 1 kHz (13.9 % at 500 Hz), and still by 1.4 % (5.7 %) with each
section pre-warped at its own corner, because the responses' slopes above the 12.5 Hz and 100 Hz
corners are warped too.  The digital filter is therefore designed as follows, once per
``(weighting, fs)`` and cached:

1. **Poles by matched z**: every analogue pole ``s`` maps exactly to ``z = exp(s / fs)``, so the
   corner frequencies and quality factors of all sections are exact at any sampling rate and
   the filter is stable by construction.
2. **Zeros by least squares**: the high-pass double zero at DC is kept exactly,
   ``(1 - z⁻¹)²``, so a static offset (gravity) is rejected exactly.  The rest of the
   numerator, of degree ``2 · sections + extra_zeros - 2``, is fitted to the *complex* analogue
   response (magnitude and phase) by linear weighted least squares on a log-spaced grid from
   ``fit_lower_hz`` to the top of the accuracy band, with Lawson's iterative reweighting towards
   the minimax (equal-ripple) relative error.  The numerator is parametrised in the scaled
   bilinear variable ``w = 2 fs (1 - z⁻¹) / (1 + z⁻¹) / ω_top`` (≈ ``j f / f_top`` in band),
   which keeps the fit well conditioned from 100 Hz to (at least) 48 kHz; its roots
   ``w_i`` map to the digital zeros ``z_i = (1 + w_i') / (1 - w_i')``, with
   ``w_i' = w_i ω_top / (2 fs)``.
3. The poles and zeros are paired into second-order sections (``scipy.signal.zpk2sos``) and
   run with ``scipy.signal.sosfilt``: a causal recursive filter, so the same coefficients
   serve batch records (:func:`weight_signal`) and streaming (:class:`WeightingFilter`).

Accuracy (checked at design time against :attr:`DigitalDesignSettings.magnitude_tolerance`,
a ``RuntimeError`` otherwise): the digital magnitude is within 1 % of the analogue one from
0.5 Hz to ``min(80 Hz, fs / 4)`` (:func:`accuracy_band`) for ``fs >= 100 Hz``.  Measured
maximum relative errors over 0.5–80 Hz: ``Wk`` 6.3e-6 / 3.0e-7 / 5.9e-9 and ``Wd``
1.0e-5 / 3.6e-7 / 7.0e-9 at 500 Hz / 1 kHz / 2 kHz, phase within 0.001°; at 100 Hz and 200 Hz
(bands to 25 and 50 Hz) below 0.5 %.  Above the band the response is not fitted: for
``fs >= 400 Hz`` it stays within 0.2 % of the analogue one up to Nyquist (measured to 10 kHz);
at lower rates it levels off where the analogue one keeps falling (at Nyquist up to 2.3 times
the analogue, but never more than 1.13 times its value at the top of the band).  Below 100 Hz
the band would end under 25 Hz and the levelled-off response would rise towards the
weighting's in-band maximum, so such rates are refused with a ``ValueError``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType, ModuleType
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from damper_emulator.errors import UserError

__all__ = [
    "BAND_LIMIT_Q",
    "DESIGN",
    "WD",
    "WEIGHTINGS",
    "WK",
    "DigitalDesignSettings",
    "UpwardStep",
    "WeightingConstants",
    "WeightingFilter",
    "accuracy_band",
    "frequency_weighting",
    "weight_signal",
    "weighting_sos",
]


def _sps() -> ModuleType:
    """``scipy.signal``, imported on first use: every ``damper-hil`` command imports this
    module while building its parser, and imported here it made each command about half a
    second slower (tests/test_layers.py keeps it out of the parser's imports)."""
    import importlib

    return importlib.import_module("scipy.signal")


BAND_LIMIT_Q: float = 1.0 / math.sqrt(2.0)
"""Quality factor of the band-limiting high- and low-pass sections (Butterworth, the ``√2`` of
ISO 2631-1:1997 Annex A, ``Hh`` and ``Hl``)."""

Start = Literal["rest", "steady"]


def _require_positive(owner: str, **values: float) -> None:
    for key, value in values.items():
        if not (math.isfinite(value) and value > 0.0):
            raise UserError(f"{owner}: {key} must be finite and positive, got {value}")


@dataclass(frozen=True)
class UpwardStep:
    """Upward step ``Hs`` of a weighting, ISO 2631-1:1997 Annex A, Table A.2.

    ``Hs = (ω5/ω6)² (1 + p/(Q5 ω5) + (p/ω5)²) / (1 + p/(Q6 ω6) + (p/ω6)²)``.

    Attributes
    ----------
    zero_hz : float
        ``f5``, frequency of the zero pair.
    zero_q : float
        ``Q5``, quality factor of the zero pair.
    pole_hz : float
        ``f6``, frequency of the pole pair.
    pole_q : float
        ``Q6``, quality factor of the pole pair.
    """

    zero_hz: float
    zero_q: float
    pole_hz: float
    pole_q: float

    def __post_init__(self) -> None:
        _require_positive("upward step", zero_hz=self.zero_hz, zero_q=self.zero_q,
                          pole_hz=self.pole_hz, pole_q=self.pole_q)


@dataclass(frozen=True)
class WeightingConstants:
    """Constants of one frequency weighting, ISO 2631-1:1997 Annex A, Table A.2.

    Attributes
    ----------
    name : str
        Weighting name as in the standard (``"Wk"``, ``"Wd"``).
    highpass_corner_hz : float
        ``f1``, corner of the band-limiting high-pass ``Hh``.
    lowpass_corner_hz : float
        ``f2``, corner of the band-limiting low-pass ``Hl``.
    transition_zero_hz : float
        ``f3``, zero of the acceleration-velocity transition ``Ht``.
    transition_pole_hz : float
        ``f4``, pole pair of the transition ``Ht``.
    transition_q : float
        ``Q4``, quality factor of the transition pole pair.
    upward_step : UpwardStep or None
        ``f5``, ``Q5``, ``f6``, ``Q6`` of the upward step ``Hs``; ``None`` where the weighting
        has none (``Hs = 1``).
    """

    name: str
    highpass_corner_hz: float
    lowpass_corner_hz: float
    transition_zero_hz: float
    transition_pole_hz: float
    transition_q: float
    upward_step: UpwardStep | None = None

    def __post_init__(self) -> None:
        _require_positive(self.name, highpass_corner_hz=self.highpass_corner_hz,
                          lowpass_corner_hz=self.lowpass_corner_hz,
                          transition_zero_hz=self.transition_zero_hz,
                          transition_pole_hz=self.transition_pole_hz,
                          transition_q=self.transition_q)


WK = WeightingConstants(
    name="Wk", highpass_corner_hz=0.4, lowpass_corner_hz=100.0,
    transition_zero_hz=12.5, transition_pole_hz=12.5, transition_q=0.63,
    upward_step=UpwardStep(zero_hz=2.37, zero_q=0.91, pole_hz=3.35, pole_q=0.91),
)
"""``Wk``: vertical (z-axis) whole-body vibration, seated/standing/recumbent (Table A.2)."""

WD = WeightingConstants(
    name="Wd", highpass_corner_hz=0.4, lowpass_corner_hz=100.0,
    transition_zero_hz=2.0, transition_pole_hz=2.0, transition_q=0.63,
)
"""``Wd``: horizontal (x- and y-axis) whole-body vibration (Table A.2); no upward step."""

WEIGHTINGS: Mapping[str, WeightingConstants] = MappingProxyType({WK.name: WK, WD.name: WD})
"""The weightings known to this module, by name."""


@dataclass(frozen=True)
class DigitalDesignSettings:
    """Settings of the digital (IIR) realisation of the weightings.

    Attributes
    ----------
    band_lower_hz, band_upper_hz : float
        Frequency range of the weightings, 0.5–80 Hz (ISO 2631-1:1997 clause 1, health,
        comfort and perception); the accuracy guarantee holds over it.
    band_fraction_of_fs : float
        The accuracy band ends at ``min(band_upper_hz, band_fraction_of_fs * fs)``.
    min_fs_hz : float
        Lowest sampling rate accepted: the accuracy band then still reaches 25 Hz, and the
        unfitted response above it stays below 1.13 times its value at the top of the band.
    fit_lower_hz : float
        Low end of the least-squares grid, below the band so that the high-pass skirt is held.
    fit_points : int
        Number of log-spaced frequencies of the least-squares grid.
    extra_zeros : int
        Numerator degree beyond the denominator's (zeros paired with poles at the origin).
    lawson_iterations : int
        Iterations of Lawson's reweighting towards the minimax relative error.
    check_points : int
        Number of log-spaced frequencies of the design-time accuracy check.
    magnitude_tolerance : float
        Largest relative magnitude error accepted by the design-time check.
    """

    band_lower_hz: float = 0.5
    band_upper_hz: float = 80.0
    band_fraction_of_fs: float = 0.25
    min_fs_hz: float = 100.0
    fit_lower_hz: float = 0.1
    fit_points: int = 400
    extra_zeros: int = 2
    lawson_iterations: int = 40
    check_points: int = 2000
    magnitude_tolerance: float = 0.01


DESIGN = DigitalDesignSettings()
"""The design settings used by :func:`weighting_sos`, :func:`weight_signal` and
:class:`WeightingFilter`."""


# --------------------------------------------------------------------------------------------
# Analogue weighting
# --------------------------------------------------------------------------------------------

def _constants(name: str) -> WeightingConstants:
    try:
        return WEIGHTINGS[name]
    except (KeyError, TypeError):
        raise UserError(
            f"unknown weighting {name!r}; known: {', '.join(sorted(WEIGHTINGS))}") from None


Polynomial = NDArray[np.float64]


def _second_order(f0_hz: float, q: float) -> Polynomial:
    """``1 + p/(Q ω0) + (p/ω0)²`` as a polynomial in ``p``, highest power first."""
    w0 = 2.0 * math.pi * f0_hz
    return np.array([1.0 / w0**2, 1.0 / (q * w0), 1.0])


def _analogue_sections(c: WeightingConstants) -> list[tuple[Polynomial, Polynomial]]:
    """Annex A factors as ``(numerator, denominator)`` polynomials in ``p``, highest power first.

    The high-pass is written ``p² / (p² + √2 ω1 p + ω1²)``, equal to Annex A's
    ``1 / (1 + √2 ω1/p + (ω1/p)²)`` and finite at ``p = 0``.
    """
    w1 = 2.0 * math.pi * c.highpass_corner_hz
    sections = [
        (np.array([1.0, 0.0, 0.0]), np.array([1.0, w1 / BAND_LIMIT_Q, w1**2])),            # Hh
        (np.array([1.0]), _second_order(c.lowpass_corner_hz, BAND_LIMIT_Q)),                 # Hl
        (np.array([1.0 / (2.0 * math.pi * c.transition_zero_hz), 1.0]),                      # Ht
         _second_order(c.transition_pole_hz, c.transition_q)),
    ]
    step = c.upward_step
    if step is not None:                                                                     # Hs
        gain = (step.zero_hz / step.pole_hz) ** 2
        sections.append((gain * _second_order(step.zero_hz, step.zero_q),
                         _second_order(step.pole_hz, step.pole_q)))
    return sections


def _analogue_response(c: WeightingConstants, f_hz: NDArray[np.float64]) -> NDArray[np.complex128]:
    p = 2j * np.pi * f_hz
    h = np.ones(np.shape(f_hz), dtype=np.complex128)
    for num, den in _analogue_sections(c):
        h *= np.polyval(num, p) / np.polyval(den, p)
    return h


def frequency_weighting(name: str, f: ArrayLike) -> np.complex128 | NDArray[np.complex128]:
    """Complex response of an ISO 2631-1 frequency weighting.

    Parameters
    ----------
    name : str
        Weighting name, ``"Wk"`` or ``"Wd"`` (see :data:`WEIGHTINGS`).
    f : array_like
        Frequencies [Hz], finite; negative frequencies give the complex conjugate.

    Returns
    -------
    h : complex or ndarray of complex
        ``Hh · Hl · Ht · Hs`` of ISO 2631-1:1997 Annex A at ``f``, the shape of ``f``.  Its
        magnitude is the weighting factor of the standard's Table 3; it is 0 at 0 Hz.

    Raises
    ------
    ValueError
        For an unknown name or non-finite frequencies.
    """
    c = _constants(name)
    f_arr = np.asarray(f, dtype=np.float64)
    if not np.all(np.isfinite(f_arr)):
        raise UserError("frequencies must be finite")
    h = _analogue_response(c, f_arr)
    return h[()] if h.ndim == 0 else h


# --------------------------------------------------------------------------------------------
# Digital filter
# --------------------------------------------------------------------------------------------

def _check_fs(fs: float, settings: DigitalDesignSettings) -> float:
    fs = float(fs)
    if not math.isfinite(fs) or fs <= 0.0:
        raise UserError(f"sampling rate must be finite and positive, got {fs}")
    if fs < settings.min_fs_hz:
        raise UserError(f"sampling rate {fs} Hz is below the minimum {settings.min_fs_hz} Hz "
                         "for the ISO 2631-1 weightings")
    return fs


def accuracy_band(fs: float, settings: DigitalDesignSettings = DESIGN) -> tuple[float, float]:
    """Frequency band [Hz] over which the digital weighting matches the analogue one.

    Parameters
    ----------
    fs : float
        Sampling rate [Hz], at least ``settings.min_fs_hz``.
    settings : DigitalDesignSettings, optional
        Design settings.

    Returns
    -------
    (f_low, f_high) : tuple of float
        ``(0.5, min(80, fs / 4))`` with the default settings; within it the magnitude error is
        below ``settings.magnitude_tolerance`` (1 %).
    """
    fs = _check_fs(fs, settings)
    return settings.band_lower_hz, min(settings.band_upper_hz, settings.band_fraction_of_fs * fs)


def _lawson_fit(basis: NDArray[np.complex128], iterations: int) -> NDArray[np.float64]:
    """Real ``c`` minimising ``max |basis @ c - 1|`` (Lawson's iteratively reweighted LS)."""
    weights = np.ones(basis.shape[0])
    coeffs = np.zeros(basis.shape[1])
    for _ in range(iterations):
        sw = np.sqrt(weights)[:, None]
        lhs = np.concatenate([(basis * sw).real, (basis * sw).imag])
        rhs = np.concatenate([sw[:, 0], np.zeros(basis.shape[0])])
        coeffs = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        err = np.abs(basis @ coeffs - 1.0)
        weights = weights * err
        weights /= weights.mean()
    return coeffs


def _design_sos(c: WeightingConstants, fs: float,
                settings: DigitalDesignSettings) -> NDArray[np.float64]:
    """Matched-z poles, least-squares zeros (see the module docstring); returns SOS."""
    f_top = min(settings.band_upper_hz, settings.band_fraction_of_fs * fs)
    w_top = 2.0 * math.pi * f_top
    sections = _analogue_sections(c)

    poles = np.concatenate([np.exp(np.roots(den) / fs) for _, den in sections])
    f = np.geomspace(settings.fit_lower_hz, f_top, settings.fit_points)
    z_inv = np.exp(-2j * np.pi * f / fs)
    denominator = np.prod(1.0 - poles[None, :] * z_inv[:, None], axis=1)
    target = _analogue_response(c, f)

    # numerator = (1 - z⁻¹)² (1 + z⁻¹)^m Σ c_k w^k, w the scaled bilinear variable
    m = poles.size + settings.extra_zeros - 2
    alpha = 2.0 * fs / w_top
    w = alpha * (1.0 - z_inv) / (1.0 + z_inv)
    common = (1.0 - z_inv) ** 2 * (1.0 + z_inv) ** m / (denominator * target)
    basis = common[:, None] * w[:, None] ** np.arange(m + 1)[None, :]
    coeffs = _lawson_fit(basis, settings.lawson_iterations)

    # (1 + z⁻¹)(w' - w_i') = (1 - w_i')(1 - z_i z⁻¹)
    # with w' = w / alpha and z_i = (1 + w_i') / (1 - w_i')
    w_roots = np.roots(coeffs[::-1]) / alpha
    zeros = np.concatenate([(1.0 + w_roots) / (1.0 - w_roots), [1.0, 1.0]])
    gain = float(np.real(coeffs[-1] * alpha**m * np.prod(1.0 - w_roots)))
    if not (np.all(np.isfinite(zeros)) and math.isfinite(gain)):
        raise RuntimeError(f"{c.name} at fs = {fs} Hz: the least-squares zeros are not finite")
    poles = np.concatenate([poles, np.zeros(zeros.size - poles.size)])
    sos: NDArray[np.float64] = _sps().zpk2sos(zeros, poles, gain)
    return sos


def _check_design(c: WeightingConstants, fs: float, sos: NDArray[np.float64],
                  settings: DigitalDesignSettings) -> float:
    f_low, f_high = accuracy_band(fs, settings)
    f = np.geomspace(f_low, f_high, settings.check_points)
    _, h = _sps().sosfreqz(sos, worN=f, fs=fs)
    error = float(np.max(np.abs(np.abs(h) / np.abs(_analogue_response(c, f)) - 1.0)))
    if not error <= settings.magnitude_tolerance:
        raise RuntimeError(f"{c.name} at fs = {fs} Hz: digital magnitude error {error:.3g} "
                           f"exceeds {settings.magnitude_tolerance:g} over {f_low}-{f_high} Hz")
    return error


@functools.lru_cache(maxsize=64)
def _cached_design(name: str, fs: float,
                   settings: DigitalDesignSettings) -> tuple[NDArray[np.float64], float]:
    c = _constants(name)
    sos = _design_sos(c, fs, settings)
    error = _check_design(c, fs, sos, settings)
    sos.setflags(write=False)
    return sos, error


def weighting_sos(name: str, fs: float,
                  settings: DigitalDesignSettings = DESIGN) -> NDArray[np.float64]:
    """Second-order sections of the digital weighting filter.

    Parameters
    ----------
    name : str
        Weighting name, ``"Wk"`` or ``"Wd"``.
    fs : float
        Sampling rate [Hz], at least ``settings.min_fs_hz`` (100 Hz).
    settings : DigitalDesignSettings, optional
        Design settings.

    Returns
    -------
    sos : ndarray, shape (n_sections, 6)
        A copy of the cached design, for ``scipy.signal.sosfilt``.  Its magnitude is within
        ``settings.magnitude_tolerance`` of :func:`frequency_weighting` over
        :func:`accuracy_band` (verified when designed).

    Raises
    ------
    ValueError
        For an unknown name or a sampling rate that is not finite or below the minimum.
    """
    _constants(name)
    return _cached_design(name, _check_fs(fs, settings), settings)[0].copy()


def _as_signal(x: ArrayLike, what: str) -> NDArray[np.float64]:
    arr = np.asarray(x, dtype=np.float64)
    if arr.ndim != 1:
        raise UserError(f"{what} must be 1-D, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise UserError(f"{what} must be finite")
    return arr


class WeightingFilter:
    """Streaming ISO 2631-1 weighting filter: the same sections as :func:`weight_signal`.

    Parameters
    ----------
    name : str
        Weighting name, ``"Wk"`` or ``"Wd"``.
    fs : float
        Sampling rate [Hz], at least 100 Hz.
    settings : DigitalDesignSettings, optional
        Design settings.

    Attributes
    ----------
    name : str
        Weighting name.
    fs : float
        Sampling rate [Hz].
    sos : ndarray, shape (n_sections, 6)
        A copy of the filter's second-order sections.
    band_hz : tuple of float
        :func:`accuracy_band` at ``fs``.
    max_magnitude_error : float
        Largest relative magnitude error over ``band_hz``, measured when designed.

    Examples
    --------
    >>> filt = WeightingFilter("Wk", 1000.0)
    >>> chunks = [filt.process(chunk) for chunk in np.array_split(record, 10)]  # doctest: +SKIP
    """

    def __init__(self, name: str, fs: float, settings: DigitalDesignSettings = DESIGN) -> None:
        _constants(name)
        self.name = name
        self.fs = _check_fs(fs, settings)
        sos, self.max_magnitude_error = _cached_design(name, self.fs, settings)
        self._sos = sos.copy()  # writable: scipy's sosfilt refuses read-only coefficients
        self.band_hz = accuracy_band(self.fs, settings)
        self._zi = np.zeros((self._sos.shape[0], 2))

    @property
    def sos(self) -> NDArray[np.float64]:
        """A copy of the filter's second-order sections, shape ``(n_sections, 6)``."""
        return self._sos.copy()

    def reset(self, initial_input: float | None = None) -> None:
        """Reset the filter state.

        Parameters
        ----------
        initial_input : float, optional
            ``None`` (default): at rest, all states zero.  A value: the steady state for a
            constant input at that value (the output then starts at 0, without the start
            transient a static offset such as gravity would excite).
        """
        if initial_input is None:
            self._zi = np.zeros((self._sos.shape[0], 2))
        else:
            x0 = float(initial_input)
            if not math.isfinite(x0):
                raise UserError("initial input must be finite")
            self._zi = _sps().sosfilt_zi(self._sos) * x0

    def process(self, chunk: ArrayLike) -> NDArray[np.float64]:
        """Weight the next chunk of the signal, continuing from the previous one.

        Parameters
        ----------
        chunk : array_like, 1-D
            The next samples (finite; may be empty).

        Returns
        -------
        y : ndarray
            The weighted samples, the length of ``chunk``.
        """
        x = _as_signal(chunk, "chunk")
        if x.size == 0:
            return x.copy()
        y: NDArray[np.float64]
        y, self._zi = _sps().sosfilt(self._sos, x, zi=self._zi)
        return y


def weight_signal(name: str, signal: ArrayLike, fs: float, *,
                  start: Start = "rest") -> NDArray[np.float64]:
    """Apply an ISO 2631-1 frequency weighting to a sampled signal.

    Parameters
    ----------
    name : str
        Weighting name, ``"Wk"`` or ``"Wd"``.
    signal : array_like, 1-D
        Acceleration samples [m/s²], finite.
    fs : float
        Sampling rate [Hz], at least 100 Hz.
    start : {"rest", "steady"}, optional
        Initial filter state: ``"rest"`` (default) starts from zero, like an instrument switched
        on at the first sample; ``"steady"`` starts in the steady state for a constant input
        equal to the first sample, so a static offset excites no start transient.

    Returns
    -------
    weighted : ndarray
        The weighted signal, the length of ``signal``.  The filter is causal (recursive, the
        sections of :func:`weighting_sos`); its magnitude is within 1 % of
        :func:`frequency_weighting` over :func:`accuracy_band`, 0.5 Hz to ``min(80 Hz, fs/4)``.
        The 0.4 Hz high-pass settles within a few seconds.

    Raises
    ------
    ValueError
        For an unknown name, a signal that is not 1-D and finite, or an unusable ``fs``.
    """
    if start not in ("rest", "steady"):
        raise UserError(f"start must be 'rest' or 'steady', got {start!r}")
    x = _as_signal(signal, "signal")
    filt = WeightingFilter(name, fs)
    if start == "steady" and x.size:
        filt.reset(initial_input=float(x[0]))
    return filt.process(x)
