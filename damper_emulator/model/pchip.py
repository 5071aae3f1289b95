"""The coefficients of the PCHIP interpolant (Fritsch & Carlson's monotone cubic), as
:class:`scipy.interpolate.PchipInterpolator` computes them.

The valve tables (:mod:`damper_emulator.model.valve_table`) need only these coefficients,
once per valve, when a model is built.  Importing ``scipy.interpolate`` for them cost every
command and node that builds a model about half a second of its start (it pulls in
``scipy.optimize``: 0.50 s of ``damper-hil replay``'s 3.4 s, and as much of the emulator's
time to active), so they are computed here, with scipy's arithmetic in scipy's order: the
same numbers bit for bit (``tests/test_model_valve.py`` checks it against scipy).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def _end_slope(h0: float, h1: float, m0: float, m1: float) -> float:
    """The derivative at an end: the one-sided three-point estimate, kept to the shape
    (Moler, *Numerical Computing with MATLAB*, §3.6, ``pchiptx``)."""
    d = ((2 * h0 + h1) * m0 - h0 * m1) / (h0 + h1)
    if np.sign(d) != np.sign(m0):
        return 0.0
    if np.sign(m0) != np.sign(m1) and abs(d) > 3.0 * abs(m0):
        return 3.0 * m0
    return float(d)


def pchip_coefficients(x: NDArray[np.float64], y: NDArray[np.float64]
                       ) -> NDArray[np.float64]:
    """The PCHIP interpolant of ``y(x)`` as ``(len(x) − 1, 4)`` local polynomial
    coefficients: on ``[x[i], x[i+1]]``, ``y = c[i,0] s³ + c[i,1] s² + c[i,2] s + c[i,3]``
    with ``s = x − x[i]`` (``PchipInterpolator(x, y).c.T``).

    Parameters
    ----------
    x : (n,) array
        Strictly increasing nodes, ``n ≥ 3``.
    y : (n,) array
        Values at the nodes.

    Notes
    -----
    The derivative at an interior node is 0 where the neighbouring slopes ``m`` differ in
    sign or one is 0, else their weighted harmonic mean with the weights ``2h_k + h_{k−1}``
    and ``h_k + 2h_{k−1}`` (Fritsch & Butland); at the ends :func:`_end_slope`.  Each
    interval is then the cubic Hermite polynomial of its ends' values and derivatives.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.ndim != 1 or x.shape != y.shape or x.size < 3:
        raise ValueError("pchip_coefficients: x and y must be 1-D, of one length >= 3")
    h = x[1:] - x[:-1]
    m = (y[1:] - y[:-1]) / h
    sm = np.sign(m)
    flat = (sm[1:] != sm[:-1]) | (m[1:] == 0) | (m[:-1] == 0)
    w1 = 2 * h[1:] + h[:-1]
    w2 = h[1:] + 2 * h[:-1]
    with np.errstate(divide="ignore", invalid="ignore"):
        whmean = (w1 / m[:-1] + w2 / m[1:]) / (w1 + w2)
        inner = 1.0 / whmean
    d = np.zeros_like(y)
    d[1:-1] = np.where(flat, 0.0, inner)
    d[0] = _end_slope(h[0], h[1], m[0], m[1])
    d[-1] = _end_slope(h[-1], h[-2], m[-1], m[-2])
    slope = np.diff(y) / h
    t = (d[:-1] + d[1:] - 2 * slope) / h
    return np.stack((t / h, (slope - d[:-1]) / h - t, d[:-1], y[:-1]), axis=1)
