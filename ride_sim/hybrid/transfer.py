"""The transfer system as the host sees it: identified before the ride, followed during it.

The host sends a stroke demand ``u[k]`` at each cycle ``k`` and receives a measured stroke
``x[k]``.  Seen from the host, the rig is the servo of :mod:`ride_sim.hybrid.actuator`
driven by the demand held over each cycle (zero-order hold), behind a pure delay ``d``
that sums the transport, the rig's cycle and the feedback's way back::

    x[k] = g · y(k − d/T),   y = servo(u),   y[k + 1] = Φ y[k] + Γ u[k]

(``T`` the cycle; ``d`` need not be a whole number of cycles).

* :func:`excitation` is the short, low-amplitude test signal run before the ride;
* :func:`identify` fits ``(d, f_servo, ζ, g)`` to it (nonlinear least squares on the time
  response, from several starts);
* :class:`TransferTracker` follows ``d`` and ``g`` during the ride (the specimen and its oil
  warm, a bus slows down): every ``period_s`` it takes the last ``window_s`` of demand and
  measurement, finds the delay by cross-correlation with the servo's response and refines it
  below a cycle by least squares on the response and its slope.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.signal import cont2discrete, lfilter

from damper_emulator.errors import UserError
from ride_sim.hybrid.params import ActuatorParams

#: Servo natural frequencies the identification starts from [Hz].
START_BANDWIDTHS_HZ = (10.0, 25.0, 60.0)
#: Bounds of the identified servo: natural frequency [Hz], damping, gain.
BANDWIDTH_BOUNDS_HZ = (1.0, 400.0)
DAMPING_BOUNDS = (0.05, 5.0)
GAIN_BOUNDS = (0.2, 5.0)
#: The largest relative change of the gain per update of the tracker.
GAIN_STEP = 0.01


@dataclass(frozen=True)
class TransferEstimate:
    """The host's model of the rig (see the module docstring)."""

    delay_s: float        # pure delay d, demand sent → measurement received [s]
    bandwidth_hz: float   # servo natural frequency [Hz]
    damping: float        # servo damping ratio [-]
    gain: float           # static gain, measured / demanded [-]
    fit_nrms: float = math.nan   # r.m.s. fit error / r.m.s. measurement [-]

    def actuator(self) -> ActuatorParams:
        """The servo as :class:`ActuatorParams` (its delay: :attr:`delay_s`)."""
        return ActuatorParams(delay_s=self.delay_s, bandwidth_hz=self.bandwidth_hz,
                              damping=self.damping, gain=self.gain)

    def to_dict(self) -> dict[str, float]:
        return {"delay_ms": self.delay_s * 1e3, "bandwidth_hz": self.bandwidth_hz,
                "damping": self.damping, "gain": self.gain, "fit_nrms": self.fit_nrms}


#: A transfer system like the rigs' (5.5 ms, 40 Hz, ζ 0.7, gain 1): what the hosts'
#: warm-ups run on before the rig's own is known.
NOMINAL_ESTIMATE = TransferEstimate(0.0055, 40.0, 0.7, 1.0)


def servo_filter(bandwidth_hz: float, damping: float, dt_s: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``(b, a)`` of the servo ``ω²/(s² + 2ζωs + ω²)`` discretised with a zero-order hold
    (:func:`scipy.signal.lfilter` form): ``y[k]`` responds to ``u[0..k−1]``."""
    w = 2.0 * math.pi * bandwidth_hz
    b, a, _ = cont2discrete(([w * w], [1.0, 2.0 * damping * w, w * w]), dt_s, "zoh")
    return np.ravel(b), np.ravel(a)


def _delayed(y: np.ndarray, shift: float) -> np.ndarray:
    """``y`` delayed by ``shift`` ≥ 0 samples, linear between samples, ``y[0]`` before."""
    k = np.arange(y.size) - shift
    out: np.ndarray = np.interp(k, np.arange(y.size), y, left=y[0])
    return out


def response(u: ArrayLike, dt_s: float, estimate: TransferEstimate) -> np.ndarray:
    """The measurement the model predicts for the demands ``u`` (from rest at ``u[0]``)."""
    u = np.asarray(u, dtype=float)
    b, a = servo_filter(estimate.bandwidth_hz, estimate.damping, dt_s)
    y = lfilter(b, a, u - u[0]) + u[0]
    return estimate.gain * _delayed(y, estimate.delay_s / dt_s)


def excitation(duration_s: float, dt_s: float, amplitude_m: float,
               band_hz: tuple[float, float] = (0.5, 30.0), seed: int = 0,
               taper_s: float = 0.3) -> np.ndarray:
    """A band-limited test signal: a multisine with equal amplitudes on the frequencies of
    the record in ``band_hz`` and random phases, tapered in and out over ``taper_s``
    (raised cosine) and scaled to a peak of ``amplitude_m``.

    Raises
    ------
    UserError
        A band with no frequency of the record in it, or a taper longer than half of it.
    """
    n = int(round(duration_s / dt_s))
    if n < 4 or 2 * taper_s > duration_s:
        raise UserError(f"excitation of {duration_s:g} s is too short for its "
                        f"{taper_s:g} s tapers")
    f = np.fft.rfftfreq(n, dt_s)
    lines = np.flatnonzero((f >= band_hz[0]) & (f <= band_hz[1]))
    if lines.size == 0:
        raise UserError(f"excitation band {band_hz} Hz holds no frequency of a "
                        f"{duration_s:g} s record")
    spectrum = np.zeros(f.size, dtype=complex)
    phases = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, lines.size)
    spectrum[lines] = np.exp(1j * phases)
    x = np.fft.irfft(spectrum, n)
    m = int(round(taper_s / dt_s))
    ramp = 0.5 - 0.5 * np.cos(np.pi * np.arange(m) / m)
    x[:m] *= ramp
    x[n - m:] *= ramp[::-1]
    out: np.ndarray = amplitude_m * x / np.max(np.abs(x))
    return out


#: The fewest cycles an identification fits.
MIN_IDENTIFICATION_CYCLES = 100


def identify(u: ArrayLike, measured: ArrayLike, dt_s: float, max_delay_s: float = 0.05,
             usable: ArrayLike | None = None) -> TransferEstimate:
    """Fit the transfer model to demands ``u`` and measurements ``measured`` (one per host
    cycle, ``dt_s`` apart), by nonlinear least squares from several starts.

    ``usable`` (boolean, one per cycle; default all) says which cycles the fit compares:
    the model still runs through the others (it needs the demands' whole history), but
    their measurements are left out.  A host leaves out the cycles a stall disturbed
    (:func:`usable_cycles`): there the rig did not get the demands on the model's
    timeline.  ``fit_nrms`` is over the usable cycles.

    Raises
    ------
    UserError
        Arrays of different lengths, too short, not finite, fewer than
        :data:`MIN_IDENTIFICATION_CYCLES` usable cycles, or a measurement that does not
        move (no rig answered).
    """
    u = np.asarray(u, dtype=float)
    x = np.asarray(measured, dtype=float)
    n_min = MIN_IDENTIFICATION_CYCLES
    if u.shape != x.shape or u.ndim != 1 or u.size < n_min:
        raise UserError(f"identification needs equal 1-D records of at least {n_min} cycles")
    keep = np.ones(u.size, bool) if usable is None else np.asarray(usable, dtype=bool)
    if keep.shape != u.shape:
        raise UserError("identification: one usable flag per cycle")
    if np.count_nonzero(keep) < n_min:
        raise UserError(f"identification: {np.count_nonzero(keep)} usable cycles (at least "
                        f"{n_min})")
    if not (np.isfinite(u).all() and np.isfinite(x[keep]).all()):
        raise UserError("identification records must be finite")
    x = x - x[keep][0] + u[0]
    if np.std(x[keep]) < 0.05 * np.std(u):
        raise UserError("the rig did not follow the identification demand (measured stroke "
                        f"r.m.s. {np.std(x[keep]) * 1e3:.3g} mm for a demand of "
                        f"{np.std(u) * 1e3:.3g} mm)")
    scale = float(np.std(x[keep]))

    def residual(p: np.ndarray) -> np.ndarray:
        est = TransferEstimate(p[0] * 1e-3, p[1], p[2], p[3])
        out: np.ndarray = (response(u, dt_s, est)[keep] - x[keep]) / scale
        return out

    # the cross-correlation's start: a left-out cycle's measurement at the demand's level
    lag = _xcorr_lag(u, np.where(keep, x, u[0]), int(max_delay_s / dt_s))
    best = None
    hi = (max_delay_s * 1e3, BANDWIDTH_BOUNDS_HZ[1], DAMPING_BOUNDS[1], GAIN_BOUNDS[1])
    lo = (0.0, BANDWIDTH_BOUNDS_HZ[0], DAMPING_BOUNDS[0], GAIN_BOUNDS[0])
    for f0 in START_BANDWIDTHS_HZ:
        d0 = min(max(0.0, lag * dt_s - 1.4 / (2.0 * math.pi * f0)), 0.9 * max_delay_s)
        fit = least_squares(residual, (d0 * 1e3, f0, 0.7, 1.0), bounds=(lo, hi),
                            x_scale=(1.0, f0, 0.3, 0.1))
        if best is None or fit.cost < best.cost:
            best = fit
    assert best is not None
    p = best.x
    nrms = float(np.sqrt(np.mean(best.fun ** 2)))
    return TransferEstimate(float(p[0]) * 1e-3, float(p[1]), float(p[2]), float(p[3]), nrms)


def usable_cycles(disturbed: ArrayLike, guard: int) -> np.ndarray:
    """The cycles an identification can compare: neither one that a stall disturbed
    (``disturbed``, one flag per cycle) nor one of the ``guard`` cycles after it, while the
    rig's delay and its servo still carry the disturbance."""
    bad = np.asarray(disturbed, dtype=bool)
    count = np.concatenate(([0], np.cumsum(bad)))
    j = np.arange(bad.size)
    recent = count[j + 1] - count[np.maximum(j - int(guard), 0)]
    out: np.ndarray = recent == 0
    return out


def stall_count(disturbed: ArrayLike) -> int:
    """The stalls in ``disturbed`` (one flag per cycle): its runs of disturbed cycles."""
    d = np.asarray(disturbed, dtype=bool)
    return int(np.count_nonzero(d[1:] & ~d[:-1]) + np.count_nonzero(d[:1]))


def _xcorr_lag(a: np.ndarray, b: np.ndarray, max_lag: int) -> int:
    """The lag ``0..max_lag`` [samples] at which ``b`` best matches ``a`` delayed."""
    a = a - a.mean()
    b = b - b.mean()
    n = a.size
    max_lag = max(0, min(max_lag, n // 2))
    scores = [float(np.dot(b[lag:], a[:n - lag])) for lag in range(max_lag + 1)]
    return int(np.argmax(scores))


class TransferTracker:
    """Follows the delay and gain of the rig during the ride (see the module docstring).

    Parameters
    ----------
    estimate : TransferEstimate
        The identified model: its servo is kept, its delay and gain are the start.
    dt_s : float
        The host's cycle [s].
    window_s, period_s : float
        Data each update uses, and how often it runs [s].
    max_delay_s : float
        Longest delay searched [s].
    min_correlation : float
        An update is kept only when the servo's delayed response explains the measurement
        this well (correlation coefficient); otherwise the estimate holds (too little
        motion, e.g. on a smooth road or while the rig holds).
    min_motion_m : float
        Nor when the window's measured stroke moves less than this (r.m.s.) [m].
    max_step_s : float
        The delay moves at most this far per update [s], the gain at most
        :data:`GAIN_STEP` of itself: a window that a stall of the host or the bus has
        disturbed moves them a little, not to its own answer.
    """

    def __init__(self, estimate: TransferEstimate, dt_s: float, window_s: float = 1.0,
                 period_s: float = 0.1, max_delay_s: float = 0.05,
                 min_correlation: float = 0.95, min_motion_m: float = 5e-4,
                 max_step_s: float = 5e-4) -> None:
        self.estimate = estimate
        self.dt_s = float(dt_s)
        self.delay_s = estimate.delay_s
        self.gain = estimate.gain
        self._window = max(16, int(round(window_s / dt_s)))
        self._period = max(1, int(round(period_s / dt_s)))
        self._max_lag = max(1, int(math.ceil(max_delay_s / dt_s)))
        self._min_corr = float(min_correlation)
        self._min_motion = float(min_motion_m)
        self._max_step = float(max_step_s)
        size = self._window + self._max_lag + 2
        self._y = np.zeros(size)
        self._x = np.zeros(size)
        self._n = 0
        b, a = servo_filter(estimate.bandwidth_hz, estimate.damping, dt_s)
        # y[k] = b1 u[k−1] + b2 u[k−2] − a1 y[k−1] − a2 y[k−2]  (b0 = 0: zero-order hold)
        self._b1, self._b2 = float(b[1]), float(b[2])
        self._a1, self._a2 = float(a[1]), float(a[2])
        self._u1 = self._u2 = self._y1 = self._y2 = 0.0
        self.updates = 0
        self.correlation = math.nan

    def start(self, demand_m: float) -> None:
        """At rest at ``demand_m`` (the servo's response history)."""
        self._u1 = self._u2 = self._y1 = self._y2 = float(demand_m)

    def push(self, demand_m: float, measured_m: float) -> bool:
        """Record one cycle: the measurement received and the demand then sent.  Returns
        True when this cycle updated the estimate."""
        y = (self._b1 * self._u1 + self._b2 * self._u2 - self._a1 * self._y1
             - self._a2 * self._y2)
        self._u2, self._u1 = self._u1, float(demand_m)
        self._y2, self._y1 = self._y1, y
        i = self._n % self._y.size
        self._y[i] = y
        self._x[i] = measured_m
        self._n += 1
        if self._n < self._y.size or self._n % self._period:
            return False
        return self._update()

    def _update(self) -> bool:
        order = (np.arange(self._y.size) + self._n) % self._y.size   # oldest first
        y = self._y[order]
        x = self._x[order]
        w = self._window
        xw = x[-w:] - x[-w:].mean()
        if float(np.sqrt(np.mean(xw * xw))) < self._min_motion:
            return False
        # y delayed by L samples over the window is y[size − w − L : size − L]: all the lags
        # at once, as rows of a strided view
        size = y.size
        lags = self._max_lag + 1
        rows = np.lib.stride_tricks.sliding_window_view(y[size - w - self._max_lag:], w)
        rows = rows[::-1][:lags]                       # row L: y delayed by L
        centred = rows - rows.mean(axis=1, keepdims=True)
        num = centred @ xw
        den = np.sqrt(np.einsum("ij,ij->i", centred, centred) * float(xw @ xw))
        with np.errstate(divide="ignore", invalid="ignore"):
            corr = np.where(den > 0, num / den, -np.inf)
        best_lag = int(np.argmax(corr))
        best = float(corr[best_lag])
        self.correlation = best
        if best < self._min_corr:
            return False
        lag = min(max(best_lag, 1), self._max_lag)
        seg = y[size - w - lag: size - lag]
        slope = (y[size - w - lag + 1: size - lag + 1]
                 - y[size - w - lag - 1: size - lag - 1]) / 2.0
        regressors = np.column_stack([seg - seg.mean(), slope - slope.mean()])
        (g, gs), *_ = np.linalg.lstsq(regressors, xw, rcond=None)
        if not (GAIN_BOUNDS[0] <= g <= GAIN_BOUNDS[1]):
            return False
        shift = -gs / g            # y(k − L − δ) ≈ y(k − L) − δ ẏ: δ = −gs / g samples
        if abs(shift) > 1.0:
            shift = math.copysign(1.0, shift)
        delay = max(0.0, (lag + shift) * self.dt_s)
        self.delay_s += min(max(delay - self.delay_s, -self._max_step), self._max_step)
        step = GAIN_STEP * self.gain
        self.gain += min(max(float(g) - self.gain, -step), step)
        self.updates += 1
        return True
