"""Identification: round trip through the command line, start independence, Jacobians,
malformed files."""

import json
import subprocess
import sys

import numpy as np
import pytest

from damper_emulator.dyno import protocols
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.identify.pipeline import identify
from damper_emulator.identify.quasi_static import fit_quasi_static, gas_force
from damper_emulator.identify.valves import fit_valve
from damper_emulator.model.compressible import simulate
from damper_emulator.model.valve import pressure_drop_array, pressure_drop_jacobian
from damper_emulator.params import load_config

pytestmark = pytest.mark.slow

CLI = [sys.executable, "-m", "damper_hil.cli"]
PAPER_SINES = ((1, 0.05), (3, 0.05), (12, 0.005))


def _run(*args, check=True):
    proc = subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True,
                          timeout=300)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory):
    """The paper's protocol on the virtual dyno with 4 N force noise, identified and
    validated through the command line."""
    d = tmp_path_factory.mktemp("rt")
    tests = [("quasi_static.csv", ["--protocol", "quasi-static", "--seed", 1]),
             ("chirp.csv", ["--protocol", "chirp", "--seed", 2])]
    tests += [(f"sine_{f}hz.csv", ["--protocol", "sine", "--frequency", f, "--amplitude", a,
                                   "--seed", 10 + k]) for k, (f, a) in enumerate(PAPER_SINES)]
    # the five dyno runs at once, each into its own folder (each writes its dyno.json):
    # one after another they took 15 s of the suite
    runs = [(name, subprocess.Popen([*CLI, "dyno", *map(str, args), "--noise-std", "4",
                                     "--no-plot", "--out", str(d / name[:-4])],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
            for name, args in tests]
    for name, proc in runs:
        _, stderr = proc.communicate(timeout=300)
        assert proc.returncode == 0, stderr
        (d / name[:-4] / name).rename(d / name)
    proc = _run("identify", "--quasi-static", d / "quasi_static.csv", "--chirp",
                d / "chirp.csv", "--out", d / "PARAMS.yaml", "--report", d / "report")
    (d / "identify.stderr").write_text(proc.stderr)
    _run("validate", "--params", d / "PARAMS.yaml", *[d / f"sine_{f}hz.csv"
                                                      for f, _ in PAPER_SINES],
         "--json", d / "validation.json")
    return d


def test_round_trip_recovers_the_parameters(round_trip, sport_cfg):
    fitted = load_config(round_trip / "PARAMS.yaml").damper
    true = sport_cfg.damper
    for key in ("gas_pressure_static_pa", "gas_volume_static_m3"):
        assert getattr(fitted, key) == pytest.approx(getattr(true, key), rel=0.02), key
    assert fitted.friction_force_n == pytest.approx(true.friction_force_n, rel=0.05)
    for side in ("rebound", "compression"):
        f, t = getattr(fitted, side), getattr(true, side)
        assert f.preload_pa == pytest.approx(t.preload_pa, rel=0.02), side
        for key in ("k_leak", "k_port", "k_spring", "smoothing_g"):
            assert getattr(f, key) == pytest.approx(getattr(t, key), rel=0.05), (side, key)
    doc = json.loads((round_trip / "PARAMS.json").read_text())
    # fit quality at the noise level (eq 34) and standard errors reported
    assert doc["quasi_static_fit"]["rms_N"] == pytest.approx(4.0, rel=0.1)
    for side in ("rebound_fit", "compression_fit"):
        assert doc[side]["rms_N"] < 6.0
        assert set(doc[side]["std_errors"]) == {"k_leak", "k_port", "k_spring", "preload_pa",
                                                "smoothing_g"}
    for png in ("quasi_static_fit.png", "valve_fit.png", "chirp_residual.png"):
        assert (round_trip / "report" / png).stat().st_size > 10_000


def test_round_trip_validates_on_the_papers_sines(round_trip):
    files = json.loads((round_trip / "validation.json").read_text())["files"]
    assert set(files) == {f"sine_{f}hz.csv" for f, _ in PAPER_SINES}
    for name, r in files.items():
        assert r["relative_rms"] < 0.02, name
        assert r["rms_N"] < 10.0, name  # the 4 N noise plus parameter error


def _virtual(cfg, model, seed):
    rng = np.random.default_rng(seed)
    out = []
    for t, x, v in (protocols.quasi_static(), protocols.chirp()):
        r = simulate(model, t, x, v)
        out.append(MeasuredData(t, x, r.force_n + rng.normal(0, 4.0, t.size), v))
    return out


def test_perturbed_starts_reach_the_same_optimum(sport_cfg, sport_model):
    qs, chirp = _virtual(sport_cfg, sport_model, 7)
    results = []
    for f in (1.0, 0.5, 1.5):
        factors = {"rebound": [f, 1 / f, f, 1 / f, f], "compression": [1 / f, f, 1 / f, f, 1 / f]}
        r = identify(qs, chirp, sport_cfg, start_factors=factors)
        results.append(np.concatenate([tuple(r.config.damper.rebound),
                                       tuple(r.config.damper.compression)]))
    np.testing.assert_allclose(results[1], results[0], rtol=1e-4)
    np.testing.assert_allclose(results[2], results[0], rtol=1e-4)


def test_valve_jacobian_matches_finite_differences(sport_cfg):
    d = sport_cfg.damper
    nu = d.oil_kinematic_viscosity_m2_s
    q = np.linspace(2e-6, 1.4e-3, 60)
    for valve in (d.rebound, d.compression):
        theta = np.array(tuple(valve))
        jac = pressure_drop_jacobian(q, theta, nu)
        for j in range(5):
            h = 1e-6 * theta[j]
            up, dn = theta.copy(), theta.copy()
            up[j] += h
            dn[j] -= h
            fd = (pressure_drop_array(q, up, nu) - pressure_drop_array(q, dn, nu)) / (2 * h)
            np.testing.assert_allclose(jac[:, j], fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


def test_fits_supply_exact_jacobians(sport_cfg, monkeypatch):
    """The residual Jacobians handed to least_squares (or the functions that compute them)
    agree with finite differences of the residuals themselves (captured at the start
    point)."""
    import damper_emulator.identify.fitting as fitting

    captured = {}
    real_fit = fitting.fit

    def spy(fun, names, start, log_scaled, lower, upper, measured, fixed=None,
            penalty_rows=0):
        captured["fun"], captured["start"] = fun, np.asarray(start, float)
        return real_fit(fun, names, start, log_scaled, lower, upper, measured, fixed,
                        penalty_rows)

    monkeypatch.setattr("damper_emulator.identify.valves.fit", spy)
    monkeypatch.setattr("damper_emulator.identify.quasi_static.fit", spy)
    d = sport_cfg.damper
    q = np.linspace(1e-5, 1.2e-3, 200)
    dp = pressure_drop_array(q, d.rebound, d.oil_kinematic_viscosity_m2_s) * 1.01
    x = np.linspace(-0.07, 0.07, 200)
    v = np.where(np.arange(200) % 2, 0.004, -0.004)
    fqs = gas_force(x, 1.02 * d.gas_pressure_static_pa, 0.9 * d.gas_volume_static_m3,
                    d.rod_area_m2, d.gas_gamma) + 40 * np.sign(v)
    for call in (lambda: fit_valve(q, dp, d.annulus_area_m2, d.oil_kinematic_viscosity_m2_s),
                 lambda: fit_quasi_static(x, v, fqs, d.rod_area_m2, d.gas_gamma)):
        call()
        fun, theta = captured["fun"], captured["start"]
        _, jac = fun(theta)
        jac = jac() if callable(jac) else jac  # the valve fit's is computed on demand
        for j in range(theta.size):
            h = 1e-6 * max(abs(theta[j]), 1.0)
            up, dn = theta.copy(), theta.copy()
            up[j] += h
            dn[j] -= h
            fd = (fun(up)[0] - fun(dn)[0]) / (2 * h)
            np.testing.assert_allclose(jac[:, j], fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


@pytest.mark.parametrize(("body", "words"), [
    ("time,displacement\n0,0\n0.001,0\n", "force"),
    ("time,displacement,force\n0,0,1\n0.001,nan,1\n0.002,0,1\n", "row 2"),
    ("time,displacement,force\n0,0,1\n0.002,0,1\n0.001,0,1\n", "row 3"),
    ("time,displacement,force\n0,0,1\n0.001,25.0,1\n0.002,-25.0,1\n", "millimetres"),
])
def test_malformed_files_exit_2_with_one_line(tmp_path, cli, body, words):
    good = tmp_path / "good.csv"
    t, x, v = protocols.quasi_static(amplitude_m=0.01, cycles=1)
    good.write_text("time,displacement,force\n" + "".join(
        f"{a},{b},{-400 + 3000 * b + 40 * np.sign(c)}\n" for a, b, c in zip(t, x, v)))
    bad = tmp_path / "bad.csv"
    bad.write_text(body)
    proc = cli("identify", "--quasi-static", good, "--chirp", bad, "--out",
               tmp_path / "P.yaml")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "bad.csv" in lines[0] and words in lines[0], proc.stderr
    assert not (tmp_path / "P.yaml").exists()


def test_paper_procedure_without_correction_is_biased(sport_cfg, sport_model):
    """Why the compressibility correction exists: the paper's filter alone leaves the
    hysteresis of the compressible data in the rebound fit (docs/identification.md)."""
    qs, chirp = _virtual(sport_cfg, sport_model, 3)
    plain = identify(qs, chirp, sport_cfg, correct_compressibility=False)
    corrected = identify(qs, chirp, sport_cfg)
    assert plain.rebound.rms > 10 * corrected.rebound.rms


def test_compressibility_correction_at_a_low_sample_rate(sport_cfg, sport_model):
    """At 300 Hz (the FSAE rig) the derivative window is still long enough for its order,
    and on noise-free data the corrected flow recovers the model's own valve flow."""
    from damper_emulator.identify.pipeline import valve_flow_and_pressure_drop

    d = sport_cfg.damper
    t, x, v = protocols.sine(1.0, 0.02, cycles=2, rate_hz=300.0)
    r = simulate(sport_model, t, x, v)
    q, dp, _ = valve_flow_and_pressure_drop(t, x, v, r.force_n, d, d.gas_pressure_static_pa,
                                            d.gas_volume_static_m3, d.friction_force_n)
    reb, com = sport_model.tables
    q_model = np.where(dp >= 0, reb.flow(np.abs(dp)), -com.flow(np.abs(dp)))
    fast = np.abs(v) > 0.2 * np.abs(v).max()
    rigid = v * d.annulus_area_m2
    # the correction removes most of the compressibility lag between rigid and true flow
    assert (np.sqrt(np.mean((q - q_model)[fast] ** 2))
            < 0.2 * np.sqrt(np.mean((rigid - q_model)[fast] ** 2)))


# ---- held parameters, several files per test, the α search, invertibility -------------


def test_held_parameter_stays_and_the_others_are_recovered(sport_cfg):
    """Noise-free Δp(Q) of the sport rebound valve: with G held at its true value and the
    other four started 30 % off, the fit returns G untouched and the rest exactly."""
    d = sport_cfg.damper
    nu = d.oil_kinematic_viscosity_m2_s
    true = np.array(tuple(d.rebound), float)
    q = np.linspace(2e-5, 1.5e-3, 300)
    dp = pressure_drop_array(q, true, nu)
    start = true * np.array([1.3, 0.7, 1.3, 0.7, 1.0])
    start[4] = 3.0  # a wrong G that the held value must replace
    fit = fit_valve(q, dp, d.annulus_area_m2, nu, start=start,
                    fixed={"smoothing_g": true[4]})
    assert fit.values[4] == true[4] and fit.std_errors[4] == 0.0
    assert fit.fixed == ("smoothing_g",)
    np.testing.assert_allclose(fit.values[:4], true[:4], rtol=1e-5)
    assert fit.rms < 1e-6


def test_a_repeated_valve_fit_keeps_its_first_bounds(sport_cfg):
    """``identify`` repeats each valve fit from its last result, one quasi-static ↔ chirp
    round after another.  A constant the data push down (here the port restriction of a
    characteristic without one) stops at the first start's bound, ÷ ``K_BOUND_FACTOR``:
    with bounds re-centred on each result it walks that factor lower every round (the
    sport damper with a cavity: the compression port restriction from 10¹² to 10⁻⁷)."""
    from damper_emulator.identify.valves import K_BOUND_FACTOR

    d = sport_cfg.damper
    nu = d.oil_kinematic_viscosity_m2_s
    true = np.array(tuple(d.rebound), float)
    true[1] = 0.0  # no port restriction in the data
    q = np.linspace(2e-5, 1.5e-3, 300)
    dp = pressure_drop_array(q, true, nu)
    start = np.array(tuple(d.rebound), float)
    floor = start[1] / K_BOUND_FACTOR
    first = fit_valve(q, dp, d.annulus_area_m2, nu, start=start)
    assert first.values[1] == pytest.approx(floor, rel=1e-6)
    again = fit_valve(q, dp, d.annulus_area_m2, nu, start=first.values, anchor=start)
    assert again.values[1] == pytest.approx(floor, rel=1e-6)
    # without the anchor the bounds move with the start, and the constant walks on
    walked = fit_valve(q, dp, d.annulus_area_m2, nu, start=first.values)
    assert walked.values[1] < floor / K_BOUND_FACTOR ** 0.5
    # a held value stays what the user gave, even far outside the anchor's bounds
    held = fit_valve(q, dp, d.annulus_area_m2, nu, start=first.values, anchor=start,
                     fixed={"k_port": floor / K_BOUND_FACTOR ** 2})
    assert held.values[1] == floor / K_BOUND_FACTOR ** 2


def test_a_valve_fit_on_a_linear_characteristic_stays_invertible(sport_cfg):
    """Δp ∝ Q from zero (a laminar bleed, as on the FSAE damper) pulls the preload towards
    zero, where the eq 29 extension makes eq 28 negative at low flow; the fit's penalty
    keeps ρ = H1 B0 / H0 <= 1 and the result can be tabulated (inverted)."""
    from damper_emulator.identify.valves import extension_intercept_excess
    from damper_emulator.model.valve_table import build_valve_table

    d = sport_cfg.damper
    nu = d.oil_kinematic_viscosity_m2_s
    q = np.linspace(1e-6, 5e-5, 200)
    dp = 4e9 * q  # 200 kPa at 5e-5 m³/s
    fit = fit_valve(q, dp, d.annulus_area_m2, nu, form="exact")
    assert extension_intercept_excess(fit.values, nu)[0] <= 1e-9
    table = build_valve_table(fit.values, d.annulus_area_m2, nu, "exact", 256, 1.0, "test")
    assert table.max_flow_m3_s > q.max()
    grid = np.concatenate(([0.0], np.geomspace(1e-12, 1e-3, 200)))
    assert np.all(np.diff(pressure_drop_array(grid, fit.values, nu, "exact")) > 0)


def test_intercept_penalty_gradient_matches_finite_differences(sport_cfg):
    from damper_emulator.identify.valves import extension_intercept_excess

    nu = sport_cfg.damper.oil_kinematic_viscosity_m2_s
    theta = np.array([1.8e16, 4.9e7, 2.1e12, 3.7e3, 1.5])
    _value, grad = extension_intercept_excess(theta, nu)
    for k in range(4):
        up, down = theta.copy(), theta.copy()
        up[k] *= 1 + 1e-4
        down[k] *= 1 - 1e-4
        fd = ((extension_intercept_excess(up, nu)[0] - extension_intercept_excess(down, nu)[0])
              / (theta[k] * 2e-4))
        assert grad[k] * theta[k] == pytest.approx(fd * theta[k], rel=1e-3, abs=1e-9)


def test_a_test_split_into_two_files_gives_the_same_identification(sport_cfg, sport_model):
    """Joining files: each keeps its own velocity and flow correction; the chirp cut in two
    identifies the same damper as the whole chirp (differences from the samples at the cut
    and from the speed threshold, which is relative to each file's peak)."""
    qs, chirp = _virtual(sport_cfg, sport_model, 5)
    whole = identify(qs, chirp, sport_cfg)
    cut = chirp.time.size // 2
    halves = [MeasuredData(chirp.time[s] - chirp.time[s][0], chirp.displacement[s],
                           chirp.force[s], chirp.velocity[s])
              for s in (slice(0, cut), slice(cut, None))]
    split = identify(qs, halves, sport_cfg)
    for side in ("rebound", "compression"):
        np.testing.assert_allclose(tuple(getattr(split.config.damper, side)),
                                   tuple(getattr(whole.config.damper, side)), rtol=0.02)


def test_alpha_search_recovers_the_compressibility(sport_cfg):
    """Data from a damper with 2.5× the sport α; identification from a base file with the
    sport α and --fit-alpha finds the true α (a 20 s chirp keeps the search short)."""
    import dataclasses

    from damper_emulator.model.compressible import DamperModel

    alpha_true = 2.5 * sport_cfg.damper.oil_compressibility_per_pa
    truth = DamperModel(dataclasses.replace(sport_cfg, damper=dataclasses.replace(
        sport_cfg.damper, oil_compressibility_per_pa=alpha_true)))
    rng = np.random.default_rng(11)
    data = []
    for t, x, v in (protocols.quasi_static(), protocols.chirp(duration_s=20.0)):
        data.append(MeasuredData(t, x, simulate(truth, t, x, v).force_n
                                 + rng.normal(0, 4.0, t.size), v))
    result = identify(data[0], data[1], sport_cfg, fit_alpha=True)
    assert result.alpha_fit["alpha_per_pa"] == pytest.approx(alpha_true, rel=0.05)
    assert not result.alpha_fit["at_bound"]
    from damper_emulator.identify.pipeline import chirp_simulation_rms, join_tests

    with_base_alpha = chirp_simulation_rms(identify(data[0], data[1], sport_cfg).config,
                                           join_tests(data[1])[0])
    assert result.alpha_fit["chirp_rms_N"] < 0.5 * with_base_alpha
    assert result.config.damper.oil_compressibility_per_pa == result.alpha_fit["alpha_per_pa"]


@pytest.mark.parametrize(("spec", "words"), [
    ("foo=1", "NAME one of"),
    ("smoothing_g=-1", "positive"),
    ("sideways.k_port=1e9", "NAME one of"),
    ("k_port=abc", "not a number"),
])
def test_bad_fix_option_exits_2_with_one_line(tmp_path, cli, spec, words):
    proc = cli("identify", "--quasi-static", tmp_path / "qs.csv", "--chirp",
               tmp_path / "c.csv", "--fix", spec, "--out", tmp_path / "P.yaml")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], proc.stderr


@pytest.mark.parametrize("value", ["nan", "-0.5"])
def test_bad_chirp_friction_factor_exits_2_with_one_line(tmp_path, cli, value):
    proc = cli("identify", "--quasi-static", tmp_path / "qs.csv", "--chirp",
               tmp_path / "c.csv", "--chirp-friction-factor", value, "--out",
               tmp_path / "P.yaml")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--chirp-friction-factor" in lines[0], proc.stderr


def test_a_fast_quasi_static_file_is_warned_about(round_trip, tmp_path):
    """A chirp given as the quasi-static test: one warning line naming it before the fit
    (here the fit then refuses the data with one error line); the slow file (the round
    trip's identification of the same chirp): no warning."""
    proc = _run("identify", "--quasi-static", round_trip / "chirp.csv", "--chirp",
                round_trip / "chirp.csv", "--out", tmp_path / "P.yaml", check=False)
    warnings = [ln for ln in proc.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "chirp.csv is not slow" in warnings[0], proc.stderr
    assert "Traceback" not in proc.stderr
    assert "warning:" not in (round_trip / "identify.stderr").read_text()


def test_a_capped_valve_fit_finds_the_same_valves(sport_cfg, sport_model):
    """A chirp with more usable samples than the cap (here ``max_valve_samples`` 3,000 per
    direction instead of 50,000, so the paper's chirp stands in for a long one; a diagnosis's
    re-identification takes such a cap): the valve fits take 1 in k of them, say so, and
    find the valves of the whole fit within 3 standard errors of the capped fit (its errors
    are the larger: it has fewer samples)."""
    import math

    cap = 3000
    qs, chirp = _virtual(sport_cfg, sport_model, 4)
    whole = identify(qs, chirp, sport_cfg)
    said = []
    capped = identify(qs, chirp, sport_cfg, progress=said.append, max_valve_samples=cap)
    for side in ("rebound", "compression"):
        usable = whole.chirp_samples[side]  # the uncapped fit uses every usable sample
        assert whole.chirp_samples_usable[side] == usable > cap
        stride = math.ceil(usable / cap)
        assert capped.chirp_samples_usable[side] == usable
        assert capped.chirp_samples[side] == math.ceil(usable / stride) <= cap
        assert any(f"1 in {stride} of the {usable} " in m for m in said), said
        a, b = getattr(whole, side), getattr(capped, side)
        assert np.all(np.abs(b.values - a.values) <= 3 * b.std_errors), (side, a.values,
                                                                         b.values)
        assert np.all(b.std_errors > a.std_errors)
