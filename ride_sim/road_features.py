"""Discrete road features: a flat road with one pothole, bump or step.

:func:`pothole`, :func:`bump` and :func:`step` build a flat road with one feature, a
lead-in and a lead-out, each wall as steep as the sampling allows; a tyre does not follow
such an edge (:func:`ride_sim.road_envelope.envelope` gives what it sees).
"""

from __future__ import annotations

import math
from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray

from ride_sim.road import (
    MIN_PROFILE_POINTS,
    SPACING_REL_TOL,
    FloatArray,
    RoadError,
    RoadProfile,
    check_finite,
    check_non_negative,
    check_positive,
)

#: Default sample spacing of the discrete features [m].
DEFAULT_FEATURE_SPACING_M = 0.005
#: Default flat road before a discrete feature [m] (0.5 s at 20 m/s).
DEFAULT_LEAD_IN_M = 10.0
#: Default flat road after a discrete feature, for the response to decay [m] (1.5 s at 20 m/s).
DEFAULT_LEAD_OUT_M = 30.0
#: Default pothole depth [m] (the paper's MIRA pothole geometry is not given).
DEFAULT_POTHOLE_DEPTH_M = 0.05
#: Default pothole length along the road, edge to edge at the surface [m].
DEFAULT_POTHOLE_LENGTH_M = 0.5
#: Shapes of :func:`bump`.
BUMP_SHAPES = ("cosine", "half_sine")


def _whole_samples(length_m: float, spacing_m: float, what: str) -> int:
    """``length_m / spacing_m`` as an int; it must be whole (relative tolerance)."""
    ratio = length_m / spacing_m
    count = round(ratio)
    if abs(ratio - count) > SPACING_REL_TOL * max(1.0, ratio):
        raise RoadError(f"{what} = {length_m} m is not a whole number of samples of "
                        f"spacing_m = {spacing_m} m")
    return int(count)


def _flat_grid(feature_samples: int, lead_in_m: float, lead_out_m: float,
               spacing_m: float) -> tuple[FloatArray, NDArray[np.int64]]:
    """Distances of a flat road and the feature-local sample index ``j`` (0 at its start)."""
    lead_in = check_non_negative(lead_in_m, "lead_in_m")
    lead_out = check_non_negative(lead_out_m, "lead_out_m")
    n_in = int(math.ceil(lead_in / spacing_m * (1.0 - SPACING_REL_TOL)))
    n_out = int(math.ceil(lead_out / spacing_m * (1.0 - SPACING_REL_TOL)))
    index = np.arange(n_in + feature_samples + n_out + 1)
    # (float64 and int64 at run time; numpy's stubs say floating[Any] and the platform int)
    return cast(FloatArray, spacing_m * index), cast("NDArray[np.int64]", index - n_in)


def _feature_grid(length_m: float, lead_in_m: float, lead_out_m: float, spacing_m: float
                  ) -> tuple[FloatArray, NDArray[np.int64], int]:
    """Grid of a feature ``length_m`` long (a whole number, at least MIN_PROFILE_POINTS, of
    samples) in a flat road: ``(distance, sample index from the feature start, samples in
    the feature)``."""
    spacing = check_positive(spacing_m, "spacing_m")
    n_feature = _whole_samples(check_positive(length_m, "length_m"), spacing, "length_m")
    if n_feature < MIN_PROFILE_POINTS:
        raise RoadError(f"length_m = {length_m} m must be at least {MIN_PROFILE_POINTS} "
                        f"samples of spacing_m = {spacing} m")
    distance, j = _flat_grid(n_feature, lead_in_m, lead_out_m, spacing)
    return distance, j, n_feature


def pothole(depth_m: float = DEFAULT_POTHOLE_DEPTH_M,
            length_m: float = DEFAULT_POTHOLE_LENGTH_M, *,
            lead_in_m: float = DEFAULT_LEAD_IN_M, lead_out_m: float = DEFAULT_LEAD_OUT_M,
            spacing_m: float = DEFAULT_FEATURE_SPACING_M) -> RoadProfile:
    """Rectangular pothole with sharp edges in a flat road.

    Parameters
    ----------
    depth_m : float
        Depth below the road surface [m], > 0 (default 50 mm).
    length_m : float
        Length along the road from edge to edge at the surface [m] (default 0.5 m), a
        whole number (>= 2) of samples.
    lead_in_m, lead_out_m : float
        Flat road before and after [m], rounded up to whole samples.
    spacing_m : float
        Sample spacing [m].

    Returns
    -------
    RoadProfile
        Height 0, except ``-depth_m`` at every sample strictly between the edges at
        ``lead_in`` and ``lead_in + length_m``: each wall is as steep as the sampling allows
        (one spacing wide) and the opening at the surface is exactly ``length_m``.
        Apply :func:`~ride_sim.road_envelope.envelope` for what a tyre sees.

    Notes
    -----
    The MIRA pothole of Simms & Crolla is not described in the paper; the defaults are a
    plausible urban pothole, to be tuned by a later study.
    """
    depth = check_positive(depth_m, "depth_m")
    distance, j, n_feature = _feature_grid(length_m, lead_in_m, lead_out_m, spacing_m)
    height = np.where((j > 0) & (j < n_feature), -depth, 0.0)
    return RoadProfile(distance, height, f"pothole {depth:g} m deep, {length_m:g} m long")


def bump(height_m: float, length_m: float, *,
         shape: Literal["cosine", "half_sine"] = "cosine",
         lead_in_m: float = DEFAULT_LEAD_IN_M, lead_out_m: float = DEFAULT_LEAD_OUT_M,
         spacing_m: float = DEFAULT_FEATURE_SPACING_M) -> RoadProfile:
    """Smooth bump (or dip, if ``height_m < 0``) in a flat road.

    Parameters
    ----------
    height_m : float
        Peak height [m], non-zero; negative for a dip.
    length_m : float
        Base length along the road [m], a whole number (>= 2) of samples.
    shape : {"cosine", "half_sine"}
        ``"cosine"``: ``h = H (1 - cos(2π x / L)) / 2``, continuous slope;
        ``"half_sine"``: ``h = H sin(π x / L)``, slope steps at the ends;
        ``x`` from 0 to ``L`` along the bump.
    lead_in_m, lead_out_m, spacing_m : float
        As in :func:`pothole`.
    """
    peak = check_finite(height_m, "height_m")
    if peak == 0.0:
        raise RoadError("height_m must be non-zero")
    if shape not in BUMP_SHAPES:
        raise RoadError(f"shape must be one of {BUMP_SHAPES}, got {shape!r}")
    distance, j, n_feature = _feature_grid(length_m, lead_in_m, lead_out_m, spacing_m)
    fraction = np.clip(j / n_feature, 0.0, 1.0)
    if shape == "cosine":
        profile = 0.5 * (1.0 - np.cos(math.tau * fraction))
    else:
        profile = np.sin(math.pi * fraction)
    height = np.where((j > 0) & (j < n_feature), peak * profile, 0.0)
    return RoadProfile(distance, height, f"{shape} bump {peak:g} m high, {length_m:g} m long")


def step(height_m: float, *, ramp_length_m: float = 0.0,
         lead_in_m: float = DEFAULT_LEAD_IN_M, lead_out_m: float = DEFAULT_LEAD_OUT_M,
         spacing_m: float = DEFAULT_FEATURE_SPACING_M) -> RoadProfile:
    """Step up (or down, if ``height_m < 0``) in a flat road.

    Parameters
    ----------
    height_m : float
        Step height [m], non-zero.
    ramp_length_m : float
        Length of the linear ramp [m], a whole number of samples; 0 (default) gives the
        sharpest step the sampling allows, a ramp of one spacing.
    lead_in_m, lead_out_m, spacing_m : float
        As in :func:`pothole`; the ramp starts at ``lead_in``.
    """
    rise = check_finite(height_m, "height_m")
    if rise == 0.0:
        raise RoadError("height_m must be non-zero")
    spacing = check_positive(spacing_m, "spacing_m")
    ramp = check_non_negative(ramp_length_m, "ramp_length_m")
    n_ramp = max(1, _whole_samples(ramp, spacing, "ramp_length_m"))
    distance, j = _flat_grid(n_ramp, lead_in_m, lead_out_m, spacing)
    height = rise * np.clip(j / n_ramp, 0.0, 1.0)
    return RoadProfile(distance, height, f"step {rise:g} m")
