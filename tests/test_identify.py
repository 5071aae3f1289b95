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

CLI = [sys.executable, "-m", "damper_emulator.cli"]
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
    _run("dyno", "--protocol", "quasi-static", "--noise-std", 4, "--seed", 1, "--out", d)
    _run("dyno", "--protocol", "chirp", "--noise-std", 4, "--seed", 2, "--out", d)
    for k, (f, a) in enumerate(PAPER_SINES):
        _run("dyno", "--protocol", "sine", "--frequency", f, "--amplitude", a,
             "--noise-std", 4, "--seed", 10 + k, "--out", d)
    _run("identify", "--quasi-static", d / "quasi_static.csv", "--chirp", d / "chirp.csv",
         "--out", d / "PARAMS.yaml", "--report", d / "report")
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
    """The residual Jacobians handed to least_squares agree with finite differences of the
    residuals themselves (captured at the start point)."""
    import damper_emulator.identify.fitting as fitting

    captured = {}
    real_fit = fitting.fit

    def spy(fun, names, start, log_scaled, lower, upper, measured):
        captured["fun"], captured["start"] = fun, np.asarray(start, float)
        return real_fit(fun, names, start, log_scaled, lower, upper, measured)

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
        for j in range(theta.size):
            h = 1e-6 * max(abs(theta[j]), 1.0)
            up, dn = theta.copy(), theta.copy()
            up[j] += h
            dn[j] -= h
            fd = (fun(up)[0] - fun(dn)[0]) / (2 * h)
            np.testing.assert_allclose(jac[:, j], fd, rtol=1e-4, atol=1e-6 * np.abs(fd).max())


@pytest.mark.parametrize("body, words", [
    ("time,displacement\n0,0\n0.001,0\n", "force"),
    ("time,displacement,force\n0,0,1\n0.001,nan,1\n0.002,0,1\n", "row 2"),
    ("time,displacement,force\n0,0,1\n0.002,0,1\n0.001,0,1\n", "row 3"),
    ("time,displacement,force\n0,0,1\n0.001,25.0,1\n0.002,-25.0,1\n", "millimetres"),
])
def test_malformed_files_exit_2_with_one_line(tmp_path, body, words):
    good = tmp_path / "good.csv"
    t, x, v = protocols.quasi_static(amplitude_m=0.01, cycles=1)
    good.write_text("time,displacement,force\n" + "".join(
        f"{a},{b},{-400 + 3000 * b + 40 * np.sign(c)}\n" for a, b, c in zip(t, x, v)))
    bad = tmp_path / "bad.csv"
    bad.write_text(body)
    proc = _run("identify", "--quasi-static", good, "--chirp", bad, "--out",
                tmp_path / "P.yaml", check=False)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "bad.csv" in lines[0] and words in lines[0], proc.stderr
    assert not (tmp_path / "P.yaml").exists()


def test_paper_procedure_without_correction_is_biased(sport_cfg, sport_model):
    """Why the compressibility correction exists: the paper's filter alone leaves the
    hysteresis of the compressible data in the rebound fit (documented in the README)."""
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
