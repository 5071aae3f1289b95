"""Tyre enveloping: the road as seen by a rigid tyre rolling on it.

A tyre does not follow a sharp edge: :func:`envelope` replaces a profile by the path of the
lowest point of a rigid circle of the tyre radius rolling over it (optionally averaged over
the contact length).
"""

from __future__ import annotations

import math

import numpy as np

from ride_sim.road import SPACING_REL_TOL, RoadProfile, check_positive

#: Suggested tyre (unloaded) radius for :func:`envelope` [m]: a passenger-car tyre such as
#: 205/55 R16 has 0.316 m; a Formula Student 20.5 in tyre has 0.26 m.
SUGGESTED_TYRE_RADIUS_M = 0.3
#: Suggested tyre contact-patch length for :func:`envelope` [m].
SUGGESTED_CONTACT_LENGTH_M = 0.15


def envelope(profile: RoadProfile, tyre_radius_m: float,
             contact_length_m: float | None = None) -> RoadProfile:
    """Tyre enveloping: the road as seen by a rigid circle of the tyre radius rolling on it.

    Parameters
    ----------
    profile : RoadProfile
        Uniformly sampled road (see :func:`~ride_sim.road.resample`).
    tyre_radius_m : float
        Tyre radius ``R`` [m], > 0 (:data:`SUGGESTED_TYRE_RADIUS_M` for a passenger car).
    contact_length_m : float, optional
        If given, the enveloped profile is then averaged by a centred moving average over
        this length (rounded to an odd number of samples, ends held), a simple model of
        the contact patch (:data:`SUGGESTED_CONTACT_LENGTH_M`).

    Returns
    -------
    RoadProfile
        Same distances, height ``h_e(s) = max_{|u| <= R} [h(s+u) + sqrt(R² - u²)] - R``:
        the height of the lowest point of the circle whose centre is above ``s`` and which
        touches the road without penetrating it (a morphological dilation of the profile
        by a semicircle).

    Notes
    -----
    The maximum is taken over the samples within ``R`` (at the ends, over those that
    exist), one pass of ``np.maximum`` per sample offset: ``O(N R / spacing)``.  Without
    averaging ``h_e >= h`` everywhere; the circle bridges a gap of width ``L < 2R`` with a
    dip of ``R - sqrt(R² - (L/2)²)`` and climbs a step early along the arc.  The
    averaging smooths the edges the circle leaves but may lower peaks below ``h``.
    """
    radius = check_positive(tyre_radius_m, "tyre_radius_m")
    spacing = profile.spacing_m
    h = np.asarray(profile.height_m)
    out = h.copy()
    offsets = min(int(math.floor(radius / spacing * (1.0 + SPACING_REL_TOL))), h.size - 1)
    for k in range(1, offsets + 1):
        u = min(k * spacing, radius)
        drop = u * u / (radius + math.sqrt(radius * radius - u * u))   # R - sqrt(R² - u²)
        np.maximum(out[:-k], h[k:] - drop, out=out[:-k])                # sample ahead
        np.maximum(out[k:], h[:-k] - drop, out=out[k:])                 # sample behind
    name = f"{profile.name} enveloped R={radius:g} m"
    if contact_length_m is not None:
        contact = check_positive(contact_length_m, "contact_length_m")
        window = 2 * int(round(contact / (2.0 * spacing))) + 1
        if window > 1:
            # imported here: scipy.ndimage is slow to import, and every command-line start
            # imports this module (the ride's parameter schema) without needing it
            from scipy.ndimage import uniform_filter1d

            out = uniform_filter1d(out, size=window, mode="nearest")
        name += f" contact {contact:g} m"
    return RoadProfile(profile.distance_m, out, name)
