"""The measurement chain as signal processing: each channel's analog low-pass filter, its
skew against the DAQ's clock, sampling and quantisation.

Two directions, two discretisations of the same analog filter:

* :func:`record_channel` makes a recording: a signal given on a fine grid (the truth
  simulation's, several points per sample) goes through the filter, the skew, the sampling
  at the file's times, additive noise and the converter's rounding.  This is what a rig
  does to the true force (``damper_emulator.diagnose.truth``).
* :func:`model_record` takes the model's force, simulated at the file's own sample times,
  to what the rig would have recorded of it: the force channel's filter, then the delay of
  the force channel relative to the displacement channel (the model is driven by the
  *recorded* displacement, late by its own filter and skew).  No quantisation: rounding is
  white noise of step²/12 to a fit, which the noise level already holds, and a rounded
  model would give the fits a cost without slope.

Both filter with the exact response of the analog filter to a signal linear between the
points it is given (scipy's ``cont2discrete(method="foh")``), each on its own grid: the
recording's on the fine grid, the model's on the samples.  The displacement channel's
filter enters :func:`model_record` as its delay at low frequency (:func:`dc_group_delay`):
a dyno's motion lies far below its channels' cut-offs, where a low-pass filter is a pure
delay to first order (its gain error at ``f`` is of order ``(f/f_c)^(2n)``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from damper_emulator.acquisition.rig import Channel, ForceChannel, RigParams, rig_to_mapping
from damper_emulator.errors import UserError

__all__ = ["ESTIMATED_DELAY_BOUND_S", "ESTIMATED_DELAY_START_S", "AcquisitionError",
           "analog_lowpass", "chain_json", "dc_group_delay", "delayed", "estimated_rig",
           "filter_samples", "force_delay", "model_record", "quantise", "record_channel",
           "relative_delay", "scaled", "unscaled"]

#: a time column whose steps differ from their median by less than this fraction is
#: filtered as uniform; otherwise it is resampled to its median step and back
UNIFORM_TOLERANCE = 1e-3
#: a record resampled for filtering may have at most this many points (a file with a long
#: gap at a fast rate would otherwise fill memory)
MAX_RESAMPLED_POINTS = 50_000_000


#: a filter whose delay at low frequency is below this fraction of the sample interval is
#: applied as that delay: on a signal linear between the samples its response is the
#: delayed signal but for transients of its own time scale at the samples, and its
#: discretisation (poles at −10⁷/step and beyond) loses that delay to rounding: an
#: estimated chain starting at no delay saw no slope in it (a 2nd-order filter at 1.5 GHz)
FAST_FILTER_FRACTION = 0.05


class AcquisitionError(UserError):
    """Acquisition settings or data the chain cannot be applied to; one line."""


def analog_lowpass(ch: Channel) -> tuple[np.ndarray, np.ndarray] | None:
    """The channel's analog filter ``H(s) = B(s)/A(s)`` as ``(b, a)`` (scipy's order:
    highest power first), ``None`` for ``filter: none``."""
    from scipy import signal  # here: most of a data reader's import time otherwise
    if not ch.filtered:
        return None
    wc = 2.0 * math.pi * ch.cutoff_hz
    if ch.filter == "butterworth":
        b, a = signal.butter(ch.order, wc, btype="low", analog=True)
    elif ch.filter == "bessel":
        b, a = signal.bessel(ch.order, wc, btype="low", analog=True, norm="mag")
    else:  # the schema's choices are the branches above
        raise AssertionError(f"filter {ch.filter!r} has no design")
    return np.atleast_1d(b), np.atleast_1d(a)


def dc_group_delay(ch: Channel) -> float:
    """The filter's group delay at zero frequency [s], ``τ = a₁/a₀ − b₁/b₀`` with
    ``H(s) = (b₀ + b₁s + …)/(a₀ + a₁s + …)`` (the slope of ``−arg H(jω)`` at ω = 0);
    0 without a filter.  A 2nd-order Butterworth filter at ``f_c``: ``√2 / (2π f_c)``."""
    ba = analog_lowpass(ch)
    if ba is None:
        return 0.0
    b, a = (np.trim_zeros(x, "f")[::-1] for x in ba)  # lowest power first
    b1 = b[1] if b.size > 1 else 0.0
    a1 = a[1] if a.size > 1 else 0.0
    return float(a1 / a[0] - b1 / b[0])


def _sos(ch: Channel, dt: float) -> np.ndarray | None:
    from scipy import signal  # here: most of a data reader's import time otherwise
    ba = analog_lowpass(ch)
    if ba is None:
        return None
    num, den, _ = signal.cont2discrete(ba, dt, method="foh")
    sos: np.ndarray = signal.tf2sos(np.ravel(num), np.ravel(den))
    return sos


def _uniform(t: np.ndarray) -> tuple[bool, float]:
    steps = np.diff(t)
    dt = float(np.median(steps))
    return bool(np.all(np.abs(steps - dt) <= UNIFORM_TOLERANCE * dt)), dt


def filter_samples(t: np.ndarray, y: np.ndarray, ch: Channel) -> np.ndarray:
    """``y`` (samples at times ``t``, increasing) through the channel's analog filter,
    from steady state at the first sample; ``y`` itself without a filter, ``y`` delayed
    by the filter's :func:`dc_group_delay` for a filter far faster than the samples
    (:data:`FAST_FILTER_FRACTION`).  A time column
    that is not uniform (jitter, gaps) is resampled to its median step, filtered and read
    back at ``t``.

    Raises
    ------
    AcquisitionError
        The resampled record would exceed :data:`MAX_RESAMPLED_POINTS`.
    """
    from scipy import signal  # here: most of a data reader's import time otherwise
    y = np.asarray(y, dtype=float)
    if not ch.filtered or y.size < 2:
        return y
    uniform, dt = _uniform(t)
    tau = dc_group_delay(ch)
    if tau < FAST_FILTER_FRACTION * dt:
        return delayed(t, y, tau)
    sos = _sos(ch, dt)
    assert sos is not None  # filtered
    if uniform:
        out, _ = signal.sosfilt(sos, y, zi=signal.sosfilt_zi(sos) * y[0])
        filtered: np.ndarray = out
        return filtered
    n = int(math.ceil((t[-1] - t[0]) / dt)) + 1
    if n > MAX_RESAMPLED_POINTS:
        raise AcquisitionError(
            f"a record of {t[-1] - t[0]:.6g} s sampled every {dt:.3g} s (median) is too "
            f"long to filter ({n} points on a uniform grid, at most "
            f"{MAX_RESAMPLED_POINTS}): split it at its gaps")
    grid = t[0] + dt * np.arange(n)
    yg = np.interp(grid, t, y)
    out, _ = signal.sosfilt(sos, yg, zi=signal.sosfilt_zi(sos) * yg[0])
    back: np.ndarray = np.interp(t, grid, out)
    return back


def delayed(t: np.ndarray, y: np.ndarray, tau: float) -> np.ndarray:
    """``y(t − τ)`` by linear interpolation (held at the ends); ``y`` for τ = 0."""
    if tau == 0.0:
        return np.asarray(y, dtype=float)
    out: np.ndarray = np.interp(t - tau, t, y)
    return out


def quantise(y: np.ndarray, ch: Channel) -> np.ndarray:
    """The converter: ``y`` rounded to steps of ``ch.adc_step`` and clipped to its range
    ``[−full_scale, full_scale − step]``; ``y`` itself for ``adc_bits: 0``."""
    if ch.adc_bits == 0:
        return y
    step = ch.adc_step
    out: np.ndarray = np.clip(np.round(y / step) * step, -ch.full_scale,
                              ch.full_scale - step)
    return out


def record_channel(t_fine: np.ndarray, y_fine: np.ndarray, ch: Channel,
                   t_samples: np.ndarray, noise_std: float = 0.0,
                   rng: np.random.Generator | None = None) -> np.ndarray:
    """What the channel records of a signal ``y_fine`` given on the fine grid ``t_fine``:
    filtered there, delayed by the skew, sampled at ``t_samples`` (within ``t_fine``),
    white noise of ``noise_std`` added (the DAQ's input noise), quantised.

    Parameters
    ----------
    t_fine, y_fine : ndarray
        The signal on a grid several times finer than the samples.
    ch : ForceChannel or DisplacementChannel
        The channel (its ``full_scale`` is the converter's range).
    t_samples : ndarray
        The file's sample times [s].
    noise_std : float
        Standard deviation of the noise added before the converter.
    rng : numpy.random.Generator, optional
        The noise's generator (required with ``noise_std > 0``).
    """
    y = filter_samples(t_fine, y_fine, ch)
    y = delayed(t_fine, y, ch.skew_s)
    out = scaled(t_samples, np.interp(t_samples, t_fine, y), ch)
    if noise_std > 0.0:
        if rng is None:
            raise ValueError("record_channel: noise needs a generator")
        out = out + rng.normal(0.0, noise_std, out.size)
    return quantise(out, ch)


def scaled(t: np.ndarray, y: np.ndarray, ch: Channel) -> np.ndarray:
    """A force channel's gain and zero on the signal ``y`` at its sample times ``t``:
    ``gain · y + zero + drift · (t − t₀)`` (``t₀`` the file's first sample); other
    channels and a calibrated force channel pass it as is."""
    if not isinstance(ch, ForceChannel) or not ch.scales:
        return y
    out: np.ndarray = (ch.gain * y + ch.zero_offset_n
                       + ch.zero_drift_n_per_s * (t - t[0]))
    return out


def unscaled(t: np.ndarray, y: np.ndarray, ch: ForceChannel) -> np.ndarray:
    """The inverse of :func:`scaled`: the force a recording ``y`` holds."""
    if not ch.scales:
        return y
    out: np.ndarray = (y - ch.zero_offset_n - ch.zero_drift_n_per_s * (t - t[0])) / ch.gain
    return out


def force_delay(rig: RigParams) -> float:
    """The delay [s] :func:`model_record` puts on the model's filtered force: the force
    channel's skew less the displacement channel's skew and filter delay."""
    return (rig.force.skew_s - rig.displacement.skew_s
            - dc_group_delay(rig.displacement))


def relative_delay(rig: RigParams) -> float:
    """How much later [s] the rig records the force than the displacement, to first order:
    the force channel's filter delay and skew less the displacement channel's."""
    return dc_group_delay(rig.force) + force_delay(rig)


#: :func:`model_record` extends each end of a record by the parabola through its
#: this many end points (a local Taylor series: value, slope and curvature go on)
EXTENSION_POINTS = 5


def _extended(t: np.ndarray, y: np.ndarray, n: int
              ) -> tuple[np.ndarray, np.ndarray, slice]:
    """``(t, y)`` extended by ``n`` points at each end (at the end steps), each end by the
    parabola fitted to its :data:`EXTENSION_POINTS` end points; and the slice of the
    original points.  (Measured on a 12 Hz sine through a 100 Hz 2nd-order filter and a
    1 ms skew at 1 kHz: the recording's first 10 samples within 0.6–4.4 N of the filter's
    run over the sine's whole past, per 1000 N of amplitude; a constant start 15–168 N,
    a straight line 2–29 N, the parabola through 9 points 2–12 N.)"""
    m = min(EXTENSION_POINTS, y.size)
    if n <= 0 or m < 3:
        return t, y, slice(0, y.size)
    dt0, dt1 = t[1] - t[0], t[-1] - t[-2]
    head_t = t[0] - dt0 * np.arange(n, 0, -1)
    tail_t = t[-1] + dt1 * np.arange(1, n + 1)
    head = np.polyval(np.polyfit(t[:m] - t[0], y[:m], 2), head_t - t[0])
    tail = np.polyval(np.polyfit(t[-m:] - t[-1], y[-m:], 2), tail_t - t[-1])
    return (np.concatenate([head_t, t, tail_t]), np.concatenate([head, y, tail]),
            slice(n, n + y.size))


#: :func:`model_record` extends a record at both ends by this many of its chain's time
#: scale (its delays and filter delays), so that the filter starts settled on the motion
#: and a delay reads no held end
SETTLE_TIME_CONSTANTS = 3.0


def model_record(t: np.ndarray, force: np.ndarray, rig: RigParams) -> np.ndarray:
    """The model's force ``force`` (simulated at the file's times ``t`` on the recorded
    displacement) as the rig records it: the force channel's filter, then
    :func:`force_delay` (module docstring).  The record is extended at both ends, odd
    about its end points, for :data:`SETTLE_TIME_CONSTANTS` × the chain's time scale: a
    real recording's filter has been running on the motion before the first sample."""
    tau = force_delay(rig)
    scale = abs(tau) + dc_group_delay(rig.force)
    if scale == 0.0 or force.size < 2:
        return scaled(t, np.asarray(force, dtype=float), rig.force)
    dt = float(np.median(np.diff(t)))
    n = int(math.ceil(SETTLE_TIME_CONSTANTS * scale / dt))
    te, fe, keep = _extended(t, np.asarray(force, dtype=float), n)
    out = delayed(te, filter_samples(te, fe, rig.force), tau)
    return scaled(t, out[keep], rig.force)


def chain_json(rig: RigParams | None) -> dict[str, Any]:
    """The ``acquisition`` member of the JSON outputs: the chain the model's force went
    through (``source``: ``given`` by ``--rig``, or ``none``), its channels, and the
    delay of the force against the displacement it amounts to."""
    if rig is None:
        return {"source": "none", "rig": None, "force_delay_s": 0.0}
    return {"source": "given", "rig": rig_to_mapping(rig)["rig"],
            "force_delay_s": relative_delay(rig)}


#: The delay of the force against the displacement a diagnosis estimates, when no chain
#: is given, lies within ``[0, ESTIMATED_DELAY_BOUND_S]`` [s]: a 2nd-order Butterworth
#: load-cell filter at 25 Hz delays by 9 ms, and a dyno's filters lie well above the 16 Hz
#: of the paper's chirp.  Not below 0: a force recorded *earlier* than the displacement
#: is what an inertia between load cell and damper looks like (``m ẍ`` leads the damping
#: force as ``−τ dF/dt`` does; a 6 kg mass on the sport damper passed for a skew of
#: −1.3 ms and was lost to the discovery).  A rig whose displacement channel is slower
#: than its force channel must be given (``--rig``).
ESTIMATED_DELAY_BOUND_S = 0.01
#: ... and every fit starts it here [s]: inside the bounds (a least-squares start on a
#: bound crawls: scipy's trf scales a step by the distance to it, and from 0 the fit took
#: a first step of 10⁻¹⁰ s and stopped), in the range of the delays of load-cell filters
#: (1 kHz: 0.23 ms, 100 Hz: 2.3 ms), and not from the identified model, whose best delay
#: is biased by the effects it lacks (2.9 ms on an unfiltered cavitation at 500 Hz).
ESTIMATED_DELAY_START_S = 5e-4


def estimated_rig(delay_s: float) -> RigParams:
    """The chain a diagnosis fits when none is given: the force recorded ``delay_s`` late
    against the displacement.  A positive delay is a 2nd-order Butterworth filter on the
    force whose group delay at zero frequency is the delay (``f_c = √2/(2π τ)``): what a
    load-cell amplifier does; a negative one a skew (the force recorded early).  Within a
    dyno's band the two readings of a positive delay, a filter or a skew, differ in gain
    by ``(f/f_c)⁴`` (10⁻⁴ at 16 Hz through 200 Hz): the data tell the delay, not which."""
    if delay_s > 0.0:
        fc = math.sqrt(2.0) / (2.0 * math.pi * delay_s)
        return RigParams(force=ForceChannel(filter="butterworth", order=2, cutoff_hz=fc))
    if delay_s < 0.0:
        return RigParams(force=ForceChannel(skew_s=delay_s))
    return RigParams()
