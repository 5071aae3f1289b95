"""Tests of the road modules (ride_sim.road and its road_* siblings): spectra, random roads,
features, tyre enveloping, files, speed."""

import itertools
import math

import numpy as np
import pytest
from scipy import integrate, signal

from ride_sim.road import RoadError, RoadProfile, resample
from ride_sim.road_csv import read_profile_csv, write_profile_csv
from ride_sim.road_envelope import envelope
from ride_sim.road_features import DEFAULT_POTHOLE_DEPTH_M, bump, pothole, step
from ride_sim.road_spectra import band_variance, spatial_psd, temporal_psd
from ride_sim.road_speed import SpeedProfile, constant_speed, road_input
from ride_sim.road_synthesis import MINOR_ROAD, RoadRoughness, iso8608_class, random_road

G_MINOR = 5e-6
P_MINOR = 2.5
V_MINOR = 20.0


def closed_form_variance(g, p, n_lo, n_hi):
    """∫_{n_lo}^{n_hi} G n^-p dn, written out independently of the module."""
    return g * (n_lo ** (1 - p) - n_hi ** (1 - p)) / (p - 1)


# --------------------------------------------------------------------------------------
# Spectra


def test_minor_road_constants():
    assert MINOR_ROAD.roughness == G_MINOR
    assert MINOR_ROAD.waviness == P_MINOR
    # eq 39 literally: S(f) = G V^(p-1) / f^p at 1 Hz and 20 m/s
    assert temporal_psd(G_MINOR, P_MINOR, V_MINOR, 1.0) == pytest.approx(
        G_MINOR * V_MINOR ** 1.5, rel=1e-12)


def test_temporal_psd_is_spatial_psd_scaled_by_speed():
    rng = np.random.default_rng(1)
    for _ in range(20):
        g = 10 ** rng.uniform(-7, -4)
        p = rng.uniform(1.2, 3.5)
        v = rng.uniform(1.0, 40.0)
        f = 10 ** rng.uniform(-1, 2, size=7)
        expected = spatial_psd(g, p, f / v) / v        # S(f) df = S(n) dn with n = f / V
        np.testing.assert_allclose(temporal_psd(g, p, v, f), expected, rtol=1e-12)


def test_temporal_and_spatial_variance_agree():
    band = (0.02, 5.0)
    spatial, _ = integrate.quad(lambda n: spatial_psd(G_MINOR, P_MINOR, n), *band, limit=200)
    temporal, _ = integrate.quad(lambda f: temporal_psd(G_MINOR, P_MINOR, V_MINOR, f),
                                 band[0] * V_MINOR, band[1] * V_MINOR, limit=200)
    assert temporal == pytest.approx(spatial, rel=1e-8)
    assert band_variance(G_MINOR, P_MINOR, band) == pytest.approx(spatial, rel=1e-8)
    assert band_variance(G_MINOR, 1.0, band) == pytest.approx(
        G_MINOR * math.log(band[1] / band[0]), rel=1e-12)


def test_band_limited_psd_is_zero_outside():
    n = np.array([0.005, 0.01, 1.0, 10.0, 11.0])
    psd = spatial_psd(G_MINOR, P_MINOR, n, band_cycles_per_m=(0.01, 10.0))
    assert psd[0] == 0 and psd[-1] == 0 and np.all(psd[1:-1] > 0)
    f = n * V_MINOR
    psd_t = temporal_psd(G_MINOR, P_MINOR, V_MINOR, f, band_cycles_per_m=(0.01, 10.0))
    np.testing.assert_array_equal(psd_t > 0, psd > 0)


@pytest.mark.parametrize("args", [(-1.0, 2.0, 1.0), (1e-6, 0.0, 1.0), (1e-6, 2.0, 0.0),
                                  (1e-6, 2.0, np.nan), (np.inf, 2.0, 1.0)])
def test_spatial_psd_rejects_bad_input(args):
    with pytest.raises(RoadError):
        spatial_psd(*args)


def test_iso8608_classes():
    expected = dict(zip("ABCDEFGH", [16e-6, 64e-6, 256e-6, 1024e-6, 4096e-6, 16384e-6,
                                     65536e-6, 262144e-6]))
    for letter, gd in expected.items():
        cls = iso8608_class(letter)
        assert cls.waviness == 2.0
        assert cls.roughness == pytest.approx(gd * 0.1 ** 2, rel=1e-12)   # G = Gd(n0) n0^w
        assert cls.gd_n0_m3 == pytest.approx(gd, rel=1e-12)
        # same spectrum as ISO's Gd(n) = Gd(n0) (n/n0)^-w
        n = np.array([0.011, 0.1, 1.0, 2.83])
        np.testing.assert_allclose(cls.spatial_psd(n), gd * (n / 0.1) ** -2.0, rtol=1e-12)
    assert iso8608_class("c", "lower").gd_n0_m3 == pytest.approx(128e-6)
    assert iso8608_class("C", "upper").gd_n0_m3 == pytest.approx(512e-6)
    with pytest.raises(RoadError, match="class A"):
        iso8608_class("A", "lower")
    with pytest.raises(RoadError, match="class H"):
        iso8608_class("H", "upper")
    with pytest.raises(RoadError):
        iso8608_class("Z")
    with pytest.raises(RoadError):
        iso8608_class("B", "median")


# --------------------------------------------------------------------------------------
# Random roads


def test_random_road_variance_matches_closed_form():
    band = (0.01, 10.0)
    profile = random_road(G_MINOR, P_MINOR, 500.0, band_cycles_per_m=band, spacing_m=0.01,
                          seed=3)
    assert profile.length_m == pytest.approx(500.0)
    assert profile.spacing_m == pytest.approx(0.01)
    expected = closed_form_variance(G_MINOR, P_MINOR, *band)
    assert np.mean(profile.height_m) == pytest.approx(0.0, abs=1e-12)
    assert np.var(profile.height_m) == pytest.approx(expected, rel=0.02)


def test_random_road_periodogram_matches_target_deterministic_amplitudes():
    band = (0.05, 5.0)
    spacing = 0.02
    profile = random_road(G_MINOR, P_MINOR, 400.0, band_cycles_per_m=band,
                          spacing_m=spacing, seed=11)
    n, pxx = signal.periodogram(profile.height_m, fs=1.0 / spacing, window="boxcar",
                                detrend=False, scaling="density")
    dn = n[1] - n[0]
    inside = (n >= band[0] + dn) & (n <= band[1] - dn)
    outside = (n > 0) & ((n < band[0] - dn) | (n > band[1] + dn))
    target = G_MINOR * n[inside] ** -P_MINOR
    np.testing.assert_allclose(pxx[inside], target, rtol=0.02)
    assert np.max(pxx[outside]) < 1e-9 * G_MINOR * band[1] ** -P_MINOR


def test_random_road_welch_matches_target_random_amplitudes():
    """Rayleigh amplitudes: Welch PSD averaged over seeds matches G n^-p in the band."""
    band = (0.02, 5.0)
    spacing = 0.02
    seg = 4096                                  # 82 m segments, 0.012 cycles/m resolution
    psd_sum = 0.0
    seeds = range(32)            # per-seed band-average scatter ~0.19 -> ~0.035 averaged
    for seed in seeds:
        profile = random_road(G_MINOR, P_MINOR, 800.0, band_cycles_per_m=band,
                              spacing_m=spacing, seed=seed, amplitudes="random")
        n, pxx = signal.welch(profile.height_m, fs=1.0 / spacing, nperseg=seg)
        psd_sum = psd_sum + pxx
    psd = psd_sum / len(seeds)
    target = G_MINOR * n[1:] ** -P_MINOR
    ratio = psd[1:] / target
    # average the ratio over 1/3-octave bands in the interior of the band
    edges = 0.1 * 2.0 ** (np.arange(0, 16) / 3.0)          # 0.1 .. 3.2 cycles/m
    for lo, hi in itertools.pairwise(edges):
        sel = (n[1:] >= lo) & (n[1:] < hi)
        assert np.mean(ratio[sel]) == pytest.approx(1.0, abs=0.15), (lo, hi)
    above = n >= 1.5 * band[1]
    assert np.max(psd[above]) < 1e-6 * G_MINOR * band[1] ** -P_MINOR


def test_random_road_deterministic_for_seed():
    a = random_road(G_MINOR, P_MINOR, 100.0, seed=42)
    b = random_road(G_MINOR, P_MINOR, 100.0, seed=42)
    c = random_road(G_MINOR, P_MINOR, 100.0, seed=43)
    np.testing.assert_array_equal(a.height_m, b.height_m)
    np.testing.assert_array_equal(a.distance_m, c.distance_m)
    assert not np.allclose(a.height_m, c.height_m)
    r1 = random_road(G_MINOR, P_MINOR, 100.0, seed=42, amplitudes="random")
    r2 = random_road(G_MINOR, P_MINOR, 100.0, seed=42, amplitudes="random")
    np.testing.assert_array_equal(r1.height_m, r2.height_m)
    assert MINOR_ROAD.random_road(100.0, seed=42).height_m.tolist() == a.height_m.tolist()


def test_random_road_scatter_between_seeds_depends_on_synthesis():
    band = (0.05, 10.0)
    det = [np.var(random_road(G_MINOR, P_MINOR, 100.0, band_cycles_per_m=band,
                              seed=s).height_m) for s in range(5)]
    rnd = [np.var(random_road(G_MINOR, P_MINOR, 100.0, band_cycles_per_m=band, seed=s,
                              amplitudes="random").height_m) for s in range(5)]
    np.testing.assert_allclose(det, det[0], rtol=1e-9)       # no scatter of the RMS
    assert np.std(rnd) / np.mean(rnd) > 0.05                  # Gaussian process: scatter


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(band_cycles_per_m=(1.0, 0.5)), "n_max"),
    (dict(band_cycles_per_m=(0.001, 1.0)), "longer than the road"),
    (dict(band_cycles_per_m=(0.1, 60.0), spacing_m=0.01), "Nyquist"),
    (dict(amplitudes="uniform"), "amplitudes"),
    (dict(spacing_m=-0.01), "spacing_m"),
])
def test_random_road_rejects_bad_parameters(kwargs, match):
    with pytest.raises(RoadError, match=match):
        random_road(G_MINOR, P_MINOR, 100.0, **kwargs)


def test_road_seen_in_time_has_eq39_spectrum():
    """Sampling a road at constant speed gives the temporal PSD of eq 39."""
    band = (0.05, 5.0)
    spacing = 0.02
    profile = random_road(G_MINOR, P_MINOR, 300.0, band_cycles_per_m=band,
                          spacing_m=spacing, seed=5)
    dt = spacing / V_MINOR
    t = dt * np.arange(profile.distance_m.size)
    z, _ = road_input(profile, V_MINOR, t)
    f, pxx = signal.periodogram(z, fs=1.0 / dt, window="boxcar", detrend=False)
    df = f[1] - f[0]
    inside = (f >= V_MINOR * band[0] + df) & (f <= V_MINOR * band[1] - df)
    np.testing.assert_allclose(pxx[inside],
                               temporal_psd(G_MINOR, P_MINOR, V_MINOR, f[inside]), rtol=0.02)


# --------------------------------------------------------------------------------------
# RoadProfile


def test_profile_interpolation_and_slope():
    p = RoadProfile([0.0, 1.0, 3.0], [0.0, 0.2, -0.2], "tri")
    assert p.length_m == 3.0
    np.testing.assert_allclose(p.height_at([0.5, 1.0, 2.0, 3.0]), [0.1, 0.2, 0.0, -0.2])
    np.testing.assert_allclose(p.slope_at([0.5, 1.0, 2.0, 3.0]), [0.2, -0.2, -0.2, -0.2])
    # holds the end value up to one sample beyond, slope 0 there
    assert p.height_at(-0.9) == 0.0 and p.slope_at(-0.9) == 0.0
    assert p.height_at(4.9) == -0.2 and p.slope_at(4.9) == 0.0
    with pytest.raises(RoadError, match="off the road"):
        p.height_at(5.1)
    with pytest.raises(RoadError, match="off the road"):
        p.slope_at([0.0, -1.5])
    assert np.ndim(p.height_at(0.5)) == 0 and np.ndim(p.slope_at(0.5)) == 0
    with pytest.raises(ValueError, match="read-only"):
        p.height_m[0] = 1.0                                   # read-only


def test_slope_is_derivative_of_height():
    p = random_road(G_MINOR, P_MINOR, 50.0, band_cycles_per_m=(0.05, 10.0), spacing_m=0.01)
    s = np.linspace(1.0, 49.0, 1001) + 0.003
    ds = 1e-4                                  # within one segment (away from samples)
    fd = (p.height_at(s + ds) - p.height_at(s - ds)) / (2 * ds)
    on_knot = np.abs((s + 0.5 * 0.01) % 0.01 - 0.5 * 0.01) < 2 * ds
    np.testing.assert_allclose(p.slope_at(s)[~on_knot], fd[~on_knot], rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize(("d", "h", "match"), [
    ([0.0, 1.0, 1.0], [0, 0, 0], r"distance_m\[2\]"),
    ([0.0, 2.0, 1.0], [0, 0, 0], "not greater"),
    ([0.0, 1.0], [0.0, np.nan], "not finite"),
    ([0.0, 1.0], [0.0], "samples"),
    ([0.0], [0.0], "at least 2"),
])
def test_profile_validation(d, h, match):
    with pytest.raises(RoadError, match=match):
        RoadProfile(np.array(d, float), np.array(h, float), "bad")


def test_spacing_and_resample():
    p = RoadProfile([0.0, 1.0, 3.0], [0.0, 0.2, -0.2], "tri")
    with pytest.raises(RoadError, match="not uniformly sampled"):
        _ = p.spacing_m
    q = resample(p, 0.5)
    assert q.spacing_m == pytest.approx(0.5)
    np.testing.assert_allclose(q.height_at([1.0, 2.0]), [0.2, 0.0])


# --------------------------------------------------------------------------------------
# Discrete features


def test_pothole_geometry():
    p = pothole(0.05, 0.5, lead_in_m=2.0, lead_out_m=3.0, spacing_m=0.005)
    assert p.length_m == pytest.approx(5.5)
    assert p.height_at(2.0) == 0.0 and p.height_at(2.5) == 0.0
    assert p.height_at(2.005) == pytest.approx(-0.05)
    assert p.height_at(2.495) == pytest.approx(-0.05)
    assert np.min(p.height_m) == -0.05
    below = p.distance_m[p.height_m < 0]
    assert below[0] == pytest.approx(2.005) and below[-1] == pytest.approx(2.495)
    d = pothole()
    assert np.min(d.height_m) == -DEFAULT_POTHOLE_DEPTH_M
    with pytest.raises(RoadError, match="whole number"):
        pothole(0.05, 0.503, spacing_m=0.005)
    with pytest.raises(RoadError, match="depth_m"):
        pothole(-0.05)


@pytest.mark.parametrize("shape", ["cosine", "half_sine"])
def test_bump_geometry(shape):
    p = bump(0.08, 2.0, shape=shape, lead_in_m=1.0, lead_out_m=1.0, spacing_m=0.01)
    assert p.height_at(2.0) == pytest.approx(0.08)
    assert p.height_at(1.0) == 0.0 and p.height_at(3.0) == 0.0
    assert np.all(p.height_m >= 0) and np.max(p.height_m) == pytest.approx(0.08)
    if shape == "cosine":
        assert p.height_at(1.5) == pytest.approx(0.04)
    else:
        assert p.height_at(1.5) == pytest.approx(0.08 * math.sin(math.pi / 4))


def test_step_geometry():
    p = step(0.03, lead_in_m=1.0, lead_out_m=2.0, spacing_m=0.01)
    assert p.height_at(1.0) == 0.0 and p.height_at(1.01) == pytest.approx(0.03)
    assert p.height_m[-1] == pytest.approx(0.03)
    r = step(-0.02, ramp_length_m=0.5, lead_in_m=1.0, lead_out_m=1.0, spacing_m=0.01)
    assert r.height_at(1.25) == pytest.approx(-0.01)
    assert r.height_m[-1] == pytest.approx(-0.02)


# --------------------------------------------------------------------------------------
# Tyre enveloping


def test_envelope_flat_road_unchanged():
    flat = RoadProfile(np.arange(0.0, 5.0, 0.01), np.full(500, 0.123), "flat")
    np.testing.assert_array_equal(envelope(flat, 0.3).height_m, flat.height_m)
    np.testing.assert_allclose(envelope(flat, 0.3, 0.15).height_m, flat.height_m, rtol=1e-14)


def test_envelope_bridges_narrow_pothole():
    radius, width, depth = 0.3, 0.2, 0.05
    bridge = radius - math.sqrt(radius ** 2 - (width / 2) ** 2)      # 17.2 mm
    assert bridge < depth
    p = pothole(depth, width, lead_in_m=1.0, lead_out_m=1.0, spacing_m=0.005)
    e = envelope(p, radius)
    assert np.min(e.height_m) == pytest.approx(-bridge, rel=1e-9)
    # deepest in the middle of the hole
    assert e.distance_m[np.argmin(e.height_m)] == pytest.approx(1.1)


def test_envelope_reaches_floor_of_wide_pothole():
    p = pothole(0.05, 2.0, lead_in_m=1.0, lead_out_m=1.0, spacing_m=0.005)
    e = envelope(p, 0.3)
    assert np.min(e.height_m) == pytest.approx(-0.05)
    # the circle touches the floor once both edges are far enough: edge drop >= depth
    reach = math.sqrt(0.3 ** 2 - (0.3 - 0.05) ** 2)                  # 0.166 m
    floor = np.isclose(e.height_m, -0.05)
    assert e.distance_m[floor][0] == pytest.approx(1.0 + reach, abs=0.006)
    assert e.distance_m[floor][-1] == pytest.approx(3.0 - reach, abs=0.006)


def test_envelope_climbs_step_along_the_arc():
    radius, rise = 0.3, 0.04
    p = step(rise, lead_in_m=1.0, lead_out_m=1.0, spacing_m=0.005)
    e = envelope(p, radius)
    x = np.linspace(0.0, 0.3, 61)                         # distance before the step edge
    # circle resting on the corner (1.005, rise) with its centre at 1.005 - x
    expected = np.maximum(0.0, rise - (radius - np.sqrt(radius ** 2 - x ** 2)))
    np.testing.assert_allclose(e.height_at(1.005 - x), expected, atol=1e-12)


def test_envelope_never_below_profile():
    rough = random_road(G_MINOR, P_MINOR, 60.0, band_cycles_per_m=(0.05, 20.0),
                        spacing_m=0.005, seed=2)
    for profile in (rough, pothole(), bump(0.05, 0.3), step(-0.05)):
        for radius in (0.05, 0.3):
            assert np.all(envelope(profile, radius).height_m >= profile.height_m)


def test_envelope_contact_averaging_and_validation():
    p = pothole(0.05, 0.5, lead_in_m=1.0, lead_out_m=1.0, spacing_m=0.005)
    e = envelope(p, 0.3)
    a = envelope(p, 0.3, contact_length_m=0.15)
    assert np.max(np.abs(np.diff(a.height_m))) < np.max(np.abs(np.diff(e.height_m)))
    assert np.mean(a.height_m) == pytest.approx(np.mean(e.height_m), rel=1e-9)
    with pytest.raises(RoadError, match="uniformly"):
        envelope(RoadProfile([0.0, 1.0, 3.0], [0.0, 0.0, 0.0]), 0.3)
    with pytest.raises(RoadError, match="tyre_radius_m"):
        envelope(p, 0.0)


def test_envelope_is_fast_enough_for_long_profiles():
    import time

    p = random_road(G_MINOR, P_MINOR, 250.0, spacing_m=0.005)      # 50k samples
    start = time.perf_counter()
    envelope(p, 0.35, 0.15)
    assert time.perf_counter() - start < 2.0


# --------------------------------------------------------------------------------------
# Files


def test_csv_round_trip(tmp_path):
    p = random_road(G_MINOR, P_MINOR, 20.0, band_cycles_per_m=(0.1, 10.0), seed=9)
    path = tmp_path / "road.csv"
    write_profile_csv(p, path)
    q = read_profile_csv(path)
    np.testing.assert_array_equal(q.distance_m, p.distance_m)
    np.testing.assert_array_equal(q.height_m, p.height_m)
    assert q.name == "road"


def test_csv_extra_columns_comments_and_order(tmp_path):
    path = tmp_path / "measured.csv"
    path.write_text("# measured profile\nHeight, time ,Distance\n0.1,0,0\n\n0.2,1,0.5\n"
                    "0.3,2,1.5\n")
    p = read_profile_csv(path, name="m")
    np.testing.assert_array_equal(p.distance_m, [0.0, 0.5, 1.5])
    np.testing.assert_array_equal(p.height_m, [0.1, 0.2, 0.3])
    assert p.name == "m"


@pytest.mark.parametrize(("text", "match"), [
    ("distance,z\n0,0\n1,0\n", r"line 1: missing column 'height'"),
    ("distance,height\n0,0\n1,nan\n", r"line 3: height 'nan' is not finite"),
    ("distance,height\n0,0\n2,0\n1,0\n", r"line 4: distance 1 m is not greater than 2 m"),
    ("distance,height\n0,0\n1,0\n1,0\n", r"line 4: distance 1 m is not greater"),
    ("distance,height\n0,0\n1,abc\n", r"line 3: height 'abc' is not a number"),
    ("distance,height\n0,0\n1\n", r"line 3: missing value for column 'height'"),
    ("distance,height\n0,0\n", "at least 2 data rows"),
    ("", "empty file"),
])
def test_csv_malformed(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(RoadError, match=match) as info:
        read_profile_csv(path)
    message = str(info.value)
    assert str(path) in message and "\n" not in message


def test_csv_missing_file(tmp_path):
    with pytest.raises(RoadError, match="cannot read"):
        read_profile_csv(tmp_path / "none.csv")


# --------------------------------------------------------------------------------------
# Speed and road input


def test_distance_constant_acceleration():
    v0, a, duration = 5.0, 1.5, 8.0
    sp = SpeedProfile(np.array([0.0, duration]), np.array([v0, v0 + a * duration]))
    t = np.linspace(0.0, duration, 37)
    np.testing.assert_allclose(sp.distance_at(t), v0 * t + 0.5 * a * t ** 2, rtol=1e-13)
    np.testing.assert_allclose(sp.speed_at(t), v0 + a * t, rtol=1e-13)
    assert sp.total_distance_m == pytest.approx(v0 * duration + 0.5 * a * duration ** 2)


def test_distance_piecewise_matches_quadrature():
    sp = SpeedProfile(np.array([1.0, 2.0, 4.0, 4.5, 7.0]), np.array([0.0, 10.0, 25.0, 25.0, 3.0]))
    for t in (1.0, 1.3, 2.0, 3.1, 4.2, 6.9, 7.0):
        expected, _ = integrate.quad(lambda u: float(sp.speed_at(u)), 1.0, t,
                                     points=[2.0, 4.0, 4.5], limit=100)
        assert sp.distance_at(t) == pytest.approx(expected, rel=1e-10, abs=1e-12)
    with pytest.raises(RoadError, match="outside the speed profile"):
        sp.distance_at(7.5)
    with pytest.raises(RoadError, match="outside the speed profile"):
        sp.speed_at(0.5)


def test_speed_profile_validation_and_constant():
    c = SpeedProfile.constant(20.0, 25.0)
    assert c.distance_at(25.0) == pytest.approx(500.0)
    assert constant_speed(20.0, 25.0).total_distance_m == pytest.approx(500.0)
    with pytest.raises(RoadError, match="negative"):
        SpeedProfile(np.array([0.0, 1.0]), np.array([1.0, -1.0]))
    with pytest.raises(RoadError, match="not greater"):
        SpeedProfile(np.array([0.0, 0.0]), np.array([1.0, 1.0]))
    with pytest.raises(RoadError, match="at least 2"):
        SpeedProfile(np.array([0.0]), np.array([1.0]))


def test_road_input_rate_is_time_derivative():
    p = bump(0.05, 3.0, lead_in_m=2.0, lead_out_m=2.0, spacing_m=0.001)
    sp = SpeedProfile(np.array([0.0, 1.0]), np.array([2.0, 8.0]))    # accelerating
    t = np.linspace(0.05, 0.95, 200) + 1.234e-4
    z, rate = road_input(p, sp, t)
    np.testing.assert_allclose(z, p.height_at(2.0 * t + 3.0 * t ** 2), atol=1e-15)
    dt = 1e-7
    fd = (road_input(p, sp, t + dt)[0] - road_input(p, sp, t - dt)[0]) / (2 * dt)
    np.testing.assert_allclose(rate, fd, atol=2e-3 * np.max(np.abs(rate)))
    # constant speed, with a start offset
    z2, rate2 = road_input(p, 4.0, np.array([0.0, 0.5]), start_distance_m=2.0)
    assert z2[0] == 0.0 and z2[1] == pytest.approx(p.height_at(4.0))
    assert rate2[1] == pytest.approx(p.slope_at(4.0) * 4.0)
    with pytest.raises(RoadError, match="off the road"):
        road_input(p, 4.0, np.array([3.0]))


def test_roughness_dataclass():
    r = RoadRoughness(2e-6, 2.0, "x")
    assert r.gd_n0_m3 == pytest.approx(2e-4)
    assert r.variance_m2((0.1, 1.0)) == pytest.approx(closed_form_variance(2e-6, 2.0, 0.1, 1.0))
    with pytest.raises(RoadError):
        RoadRoughness(0.0, 2.0)


def test_the_demo_refuses_a_ride_shorter_than_its_roads_longest_wave_before_any_node(
        tmp_path, capsys):
    """The ride's road is one period of ``round(V T / Δ) + 1`` samples of ``Δ = V dt``
    (``random_road``): it must hold the band's longest wavelength ``1 / n_min``.  The demo
    checks that before it starts a node or writes its folder: one line, exit 2."""
    from damper_hil.cli import main
    from damper_hil.hil_demo import DemoError, check_ride
    from ride_sim.params import load_ride_config
    from ride_sim.study_setup import band_at_speed

    cfg = load_ride_config()
    speed, dt = cfg.ride.speed_m_s, cfg.simulation.step_s
    n_min = band_at_speed(cfg.road, speed)[0]
    shortest = (1.0 / n_min - dt * speed) / speed    # (N Δ >= 1 / n_min, N = V T / Δ + 1)
    check_ride(shortest + dt)                        # a sample either side
    with pytest.raises(DemoError, match="longer than the road period"):
        check_ride(shortest - dt)
    out = tmp_path / "demo"
    assert main(["demo", "--duration", f"{0.6 * shortest:g}", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("damper-hil: error: a ride of "), err
    assert not out.exists()
