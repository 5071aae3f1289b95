"""The adaptive damper (docs/model.md §6): solenoid bypass in parallel with the piston valve,
solenoid lag, parameters, and the command plumbing of the stepper, batch simulator and
emulator core.

Checked against independent derivations: the orifice's forward law, an exact ``brentq``
solve of ``v A_annulus = Q_pv(Δp) + Q_b(Δp)`` with the forward valve characteristic
(eqs 8–29, not the inverse table), ``1 − e^(−t/t63)``; and bit for bit against the model
without a bypass.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from damper_emulator.dyno.protocols import chirp
from damper_emulator.model.adaptive import (
    bypass_area,
    bypass_coefficients,
    bypass_flow,
    bypass_pressure_drop,
    solenoid_lag,
)
from damper_emulator.model.compressible import (
    DamperModel,
    DamperStepper,
    quasi_steady_force,
    simulate,
)
from damper_emulator.model.layout import Fault
from damper_emulator.model.valve import form_code, pressure_drop
from damper_emulator.params import (
    DEFAULT_PARAMS_FILE,
    config_from_mapping,
    config_to_mapping,
    load_config,
    save_config,
)
from damper_emulator.schema import ParameterError, read_yaml

RHO, CD, LENGTH, D_COMFORT, D_NORMAL, T63 = 870.0, 0.7, 3e-3, 3.3e-3, 2.6e-3, 12e-3


@pytest.fixture(scope="module")
def plain_model(sport_cfg):
    """The sport damper without the adaptive group: the paper's model, no bypass."""
    return DamperModel(sport_cfg.replace_damper(adaptive=None))


# --------------------------------------------------------------------------------------
# the bypass law


def _coefficients(nu=21e-6):
    # independent of the module: Hagen–Poiseuille 128 μ L Q / (π d⁴) = 8 π ρ ν L Q / A²
    return 8.0 * math.pi * RHO * nu * LENGTH, RHO / (2.0 * CD * CD)


def test_bypass_coefficients_are_hagen_poiseuille_and_orifice():
    a, b = bypass_coefficients(RHO, 21e-6, LENGTH, CD)
    assert (a, b) == pytest.approx(_coefficients(), rel=1e-15)
    d = 3e-3
    area = math.pi / 4 * d * d
    q = 1e-7                       # laminar limit: Δp = 128 μ L Q / (π d⁴)
    assert (a * q / area ** 2) == pytest.approx(128 * RHO * 21e-6 * LENGTH * q
                                                / (math.pi * d ** 4), rel=1e-12)


@pytest.mark.parametrize("diameter", [0.5e-3, 2.6e-3, 3.3e-3, 8e-3])
def test_bypass_flow_inverts_the_forward_law(diameter):
    a, b = _coefficients()
    area = math.pi / 4 * diameter ** 2
    for dp in (-2e7, -3e6, -1e5, -1.0, -1e-6, 1e-6, 1.0, 10.0, 1e3, 1e5, 3e6, 2e7):
        q, dq = bypass_flow(dp, area, a, b)
        assert np.sign(q) == np.sign(dp)
        # forward law Δp = (a Q + b Q|Q|)/A²
        assert float(bypass_pressure_drop(q, area, a, b)) == pytest.approx(dp, rel=1e-12)
        # the derivative is the reciprocal of dΔp/dQ = (a + 2 b |Q|)/A²
        assert dq == pytest.approx(area ** 2 / (a + 2 * b * abs(q)), rel=1e-10)
        # the textbook quadratic root gives the same flow
        textbook = math.copysign((-a + math.sqrt(a * a + 4 * b * area ** 2 * abs(dp)))
                                 / (2 * b), dp)
        assert q == pytest.approx(textbook, rel=1e-6, abs=1e-18)
    q0, dq0 = bypass_flow(0.0, area, a, b)
    assert q0 == 0.0 and dq0 == pytest.approx(area ** 2 / a, rel=1e-15)  # finite at 0


def test_closed_bypass_passes_nothing():
    a, b = _coefficients()
    for dp in (-1e6, 0.0, 1e6):
        assert bypass_flow(dp, 0.0, a, b) == (0.0, 0.0)


def test_open_area_is_piecewise_linear_in_the_command():
    ac, an = math.pi / 4 * D_COMFORT ** 2, math.pi / 4 * D_NORMAL ** 2
    c = np.linspace(0.0, 1.0, 101)
    expected = np.interp(c, [0.0, 0.5, 1.0], [ac, an, 0.0])
    got = np.array([bypass_area(x, ac, an) for x in c])
    assert got == pytest.approx(expected, rel=1e-12, abs=1e-24)
    assert bypass_area(0.0, ac, an) == ac and bypass_area(0.5, ac, an) == an
    assert bypass_area(1.0, ac, an) == 0.0


# --------------------------------------------------------------------------------------
# quasi-steady force against an independent solve


def _independent_force(cfg, velocity, command):
    """Rigid-oil force at the static position: brentq on the piston-valve flow q of
    q + Q_b(Δp(q)) = |v| A_annulus, Δp(q) the forward valve characteristic (eqs 8–29)."""
    d = cfg.damper
    a, b = _coefficients(d.oil_kinematic_viscosity_m2_s)
    area = float(np.interp(command, [0.0, 0.5, 1.0], [math.pi / 4 * D_COMFORT ** 2,
                                                      math.pi / 4 * D_NORMAL ** 2, 0.0]))
    valve = tuple(d.rebound if velocity > 0 else d.compression)
    form = form_code(cfg.numerics.valve_form)
    nu = d.oil_kinematic_viscosity_m2_s
    q_total = abs(velocity) * d.annulus_area_m2

    def dp_of(q):
        return pressure_drop(q, *valve, nu, form)

    def orifice(dp):
        if area == 0.0:
            return 0.0
        return (-a + math.sqrt(a * a + 4 * b * area * area * dp)) / (2 * b)

    q = brentq(lambda q: q + orifice(dp_of(q)) - q_total, 0.0, q_total, xtol=1e-16,
               rtol=1e-14)
    dp = math.copysign(dp_of(q), velocity)
    return d.static_force_n + d.annulus_area_m2 * dp + math.copysign(d.friction_force_n,
                                                                     velocity)


@pytest.mark.parametrize("command", [0.0, 0.25, 0.5, 0.8, 1.0])
def test_quasi_steady_force_matches_an_independent_solve(sport_cfg, sport_model, command):
    """The stepper held at the static position with a constant velocity settles (eq 2 at
    ṗ = 0) to the force of the independent solve, within the valve table's accuracy;
    quasi_steady_force (the stepper's start) agrees with it."""
    fs = sport_cfg.damper.static_force_n
    for v in (-1.0, -0.3, -0.05, 0.05, 0.3, 1.0):
        ref = _independent_force(sport_cfg, v, command)
        stepper = DamperStepper(sport_model, 0.0, 0.0, valve_command=command)
        for _ in range(400):
            force, fault = stepper.step(0.0, v, 1e-3)
            assert fault == 0
        assert force - fs == pytest.approx(ref - fs, rel=2e-3), (command, v)
        assert quasi_steady_force(sport_model, v, command) == pytest.approx(force, rel=1e-6)


def test_settings_are_ordered_and_the_documented_ratios_hold(sport_model, sport_cfg):
    """Comfort < normal < sport in |F − F_static| at every speed and direction, monotone in
    the command; at 0.5 m/s rebound comfort is 40–50 %, normal 65–75 % of sport (docs/model.md §6,
    config/sport.yaml: 0.445 and 0.708)."""
    fs = sport_cfg.damper.static_force_n
    for v in (-1.0, -0.5, -0.1, 0.1, 0.5, 1.0):
        f = [abs(quasi_steady_force(sport_model, v, c) - fs) for c in np.linspace(0, 1, 11)]
        assert np.all(np.diff(f) > 0), v
    ratio = {name: (quasi_steady_force(sport_model, 0.5, c) - fs)
             / (quasi_steady_force(sport_model, 0.5, 1.0) - fs)
             for name, c in (("comfort", 0.0), ("normal", 0.5))}
    assert 0.40 < ratio["comfort"] < 0.50 and 0.65 < ratio["normal"] < 0.75
    assert ratio["comfort"] == pytest.approx(0.445, abs=0.002)
    assert ratio["normal"] == pytest.approx(0.708, abs=0.002)


# --------------------------------------------------------------------------------------
# the solenoid lag


def test_solenoid_lag_is_exact_first_order(sport_model):
    """c_eff after time t of a step command is 1 − e^(−t/t63) (exact per step, so it does
    not depend on how t is cut into steps); the lag acts from the step after the command."""
    for dt, steps in ((1e-3, 1), (1e-3, 5), (1e-3, 12), (0.25e-3, 48), (7e-3, 1),
                      (12e-3, 1), (2e-3, 30)):
        up = DamperStepper(sport_model, valve_command=0.0)
        up.set_valve_command(1.0)
        assert up.valve_command == 1.0 and up.effective_valve_command == 0.0
        down = DamperStepper(sport_model)
        down.set_valve_command(0.0)
        for _ in range(steps):
            up.step(0.0, 0.1, dt)
            down.step(0.0, 0.1, dt)
        t = dt * steps
        assert up.effective_valve_command == pytest.approx(1 - math.exp(-t / T63), abs=1e-13)
        assert down.effective_valve_command == pytest.approx(math.exp(-t / T63), abs=1e-13)
    # 63 % after t63
    s = DamperStepper(sport_model, valve_command=0.0)
    s.set_valve_command(1.0)
    s.step(0.0, 0.0, T63)
    assert s.effective_valve_command == pytest.approx(1 - math.exp(-1.0), abs=1e-14)


def test_lag_kernel_edges():
    assert solenoid_lag(0.3, 0.3, 1e-3, T63) == 0.3
    assert solenoid_lag(0.0, 1.0, 1e-3, 0.0) == 1.0           # no lag
    assert solenoid_lag(1.0 - 1e-13, 1.0, 1e-3, T63) == 1.0  # snapped: exactly sport


def test_invalid_input_does_not_advance_the_lag(sport_model):
    s = DamperStepper(sport_model)
    s.set_valve_command(0.0)
    _force, fault = s.step(0.0, math.nan, 1e-3)
    assert fault == Fault.INVALID_INPUT and s.effective_valve_command == 1.0
    s.step(0.0, 0.1, -1e-3)
    assert s.effective_valve_command == 1.0


def test_a_gap_applies_the_lag_then_settles(sport_model):
    """After a gap longer than numerics.settle_gap_s the state restarts from equilibrium
    at the lagged command."""
    s = DamperStepper(sport_model, 0.0, 0.3)
    s.set_valve_command(0.0)
    force, _ = s.step(0.0, 0.3, 0.2)
    c = math.exp(-0.2 / T63)
    assert s.effective_valve_command == pytest.approx(c, abs=1e-15)
    assert force == pytest.approx(quasi_steady_force(sport_model, 0.3, c), rel=1e-12)


def test_sport_settles_exactly(sport_model):
    """Back at sport the effective command reaches exactly 1: the bypass closes."""
    s = DamperStepper(sport_model, valve_command=0.0)
    s.set_valve_command(1.0)
    for _ in range(2000):
        s.step(0.0, 0.0, 1e-3)
    assert s.effective_valve_command == 1.0


# --------------------------------------------------------------------------------------
# bit identity at sport and without the group


def test_command_one_is_bit_identical_to_the_plain_model(sport_model, plain_model):
    t, x, v = chirp(0.5, 16.0, duration_s=8.0, v_start_m_s=0.05, v_end_m_s=1.5,
                    rate_hz=1000.0)
    plain = simulate(plain_model, t, x, v)
    for cmd in (1.0, np.ones(t.size)):
        sport = simulate(sport_model, t, x, v, valve_command=cmd)
        assert np.array_equal(sport.force_n, plain.force_n)
        assert np.array_equal(sport.rebound_pressure_pa, plain.rebound_pressure_pa)
    assert np.array_equal(simulate(sport_model, t, x, v).force_n, plain.force_n)
    a, b = DamperStepper(sport_model, x[0], v[0]), DamperStepper(plain_model, x[0], v[0])
    for k in range(1, t.size):
        assert a.step(x[k], v[k], 1e-3) == b.step(x[k], v[k], 1e-3)


def test_without_the_group_the_command_has_no_effect(plain_model):
    assert not plain_model.adaptive
    t, x, v = chirp(1.0, 4.0, duration_s=2.0, v_start_m_s=0.1, v_end_m_s=0.8,
                    rate_hz=1000.0)
    ref = simulate(plain_model, t, x, v).force_n
    assert np.array_equal(simulate(plain_model, t, x, v, valve_command=0.0).force_n, ref)
    cmd = np.where(np.arange(t.size) % 300 < 150, 0.0, 1.0)
    assert np.array_equal(simulate(plain_model, t, x, v, valve_command=cmd).force_n, ref)


def test_softer_settings_converge_in_the_time_step(sport_model):
    """With the bypass the stepper at 1 kHz stays within 0.5 % r.m.s. of the same model at
    10 kHz on a chirp to 1.5 m/s, no solver fault (R(z) stays monotone)."""
    for cmd in (0.0, 0.5):
        lo = chirp(0.5, 16.0, duration_s=6.0, v_start_m_s=0.05, v_end_m_s=1.5, rate_hz=1000.0)
        hi = chirp(0.5, 16.0, duration_s=6.0, v_start_m_s=0.05, v_end_m_s=1.5,
                   rate_hz=10000.0)
        r_lo = simulate(sport_model, *lo, valve_command=cmd)
        r_hi = simulate(sport_model, *hi, valve_command=cmd)
        assert not np.any(r_lo.faults & Fault.SOLVER)
        f_hi = r_hi.force_n[::10]
        err = np.sqrt(np.mean((r_lo.force_n - f_hi) ** 2)) / np.sqrt(np.mean(f_hi ** 2))
        assert err < 5e-3, (cmd, err)


def test_simulate_follows_a_command_history(sport_model):
    """Per-sample commands: the effective command is the lagged one, and the forces are the
    stepper's under the same commands."""
    n = 400
    t = np.arange(n) * 1e-3
    v = np.full(n, 0.3)
    x = 0.3 * t
    cmd = np.where(t < 0.1, 1.0, np.where(t < 0.25, 0.0, 0.5))
    res = simulate(sport_model, t, x, v, valve_command=cmd)
    k = np.arange(n)
    i = int(np.argmax(t >= 0.1))          # command 0 from sample i: lag from step i + 1
    assert res.valve_command_eff[i] == 1.0
    j = i + 20
    assert res.valve_command_eff[j] == pytest.approx(math.exp(-(j - i) * 1e-3 / T63),
                                                     abs=1e-12)
    stepper = DamperStepper(sport_model, x[0], v[0])
    for kk in k[1:]:
        stepper.set_valve_command(cmd[kk - 1])
        f, _ = stepper.step(x[kk], v[kk], 1e-3)
        assert f == pytest.approx(res.force_n[kk], rel=1e-9, abs=1e-6)
    assert res.force_n[i + 100] < 0.6 * res.force_n[i - 1]     # comfort: much softer


def test_bad_commands_are_refused(sport_model):
    s = DamperStepper(sport_model)
    for bad in (-0.01, 1.01, math.nan, math.inf, "soft", None):
        with pytest.raises(ValueError, match="valve command"):
            s.set_valve_command(bad)
    assert s.valve_command == 1.0
    s.set_valve_command(np.float64(0.25))
    assert s.valve_command == 0.25 and isinstance(s.valve_command, float)
    with pytest.raises(ValueError, match="valve command"):
        DamperStepper(sport_model, valve_command=2.0)
    t = np.arange(5) * 1e-3
    with pytest.raises(ValueError, match="valve command sample 3"):
        simulate(sport_model, t, np.zeros(5), np.zeros(5),
                 valve_command=[1.0, 1.0, 0.5, 1.5, 0.0])
    with pytest.raises(ValueError, match="shape"):
        simulate(sport_model, t, np.zeros(5), np.zeros(5), valve_command=[1.0, 0.0])
    with pytest.raises(ValueError, match="valve command"):
        simulate(sport_model, t, np.zeros(5), np.zeros(5), valve_command=math.nan)


# --------------------------------------------------------------------------------------
# parameters


def test_sport_file_defines_the_adaptive_group(sport_cfg, sport_model):
    a = sport_cfg.damper.adaptive
    assert (a.oil_density_kg_m3, a.bypass_discharge_coefficient, a.bypass_length_m,
            a.comfort_bypass_diameter_m, a.normal_bypass_diameter_m,
            a.solenoid_t63_s) == (RHO, CD, LENGTH, D_COMFORT, D_NORMAL, T63)
    assert sport_model.adaptive


def test_a_damper_without_the_group_loads():
    cfg = load_config(DEFAULT_PARAMS_FILE.parent / "fsae_ttx25_base.yaml")
    assert cfg.damper.adaptive is None
    model = DamperModel(cfg)
    assert not model.adaptive
    s = DamperStepper(model)
    s.set_valve_command(0.0)      # accepted, no effect
    assert s.step(0.0, 0.1, 1e-3)[0] == DamperStepper(model).step(0.0, 0.1, 1e-3)[0]


def test_round_trip_keeps_or_omits_the_group(tmp_path, sport_cfg):
    path = tmp_path / "a.yaml"
    save_config(sport_cfg, path)
    assert load_config(path).damper == sport_cfg.damper
    plain = sport_cfg.replace_damper(adaptive=None)
    assert "adaptive" not in config_to_mapping(plain)["/**"]["ros__parameters"]["damper"]
    save_config(plain, path)
    assert load_config(path).damper.adaptive is None


@pytest.mark.parametrize(("key", "value", "words"), [
    ("oil_density_kg_m3", -870.0, "must be positive"),
    ("oil_density_kg_m3", "oil", "must be a number"),
    ("bypass_discharge_coefficient", 0.0, r"must lie in \(0, 1\]"),
    ("bypass_discharge_coefficient", 1.2, r"must lie in \(0, 1\]"),
    ("bypass_length_m", 0.0, "must be positive"),
    ("comfort_bypass_diameter_m", -1e-3, "must not be negative"),
    ("normal_bypass_diameter_m", 4e-3, "must not exceed"),
    ("comfort_bypass_diameter_m", 0.05, "smaller than damper.piston_diameter_m"),
    ("solenoid_t63_s", math.inf, "finite"),
    ("solenoid_t63_s", None, "must be a number"),
])
def test_bad_adaptive_values_are_one_line_errors(key, value, words):
    doc = read_yaml(DEFAULT_PARAMS_FILE)
    doc["/**"]["ros__parameters"]["damper"]["adaptive"][key] = value
    with pytest.raises(ParameterError, match=words) as err:
        config_from_mapping(doc, "bad.yaml")
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("bad.yaml: ")
    assert f"damper.adaptive.{key}" in msg


def test_missing_unknown_and_malformed_adaptive_keys():
    for change, words in (
            (lambda a: a.pop("solenoid_t63_s"), "missing parameter damper.adaptive.solenoid_t63_s"),
            (lambda a: a.update(bypass_diameter_m=1e-3),
             "unknown parameter damper.adaptive.bypass_diameter_m")):
        doc = read_yaml(DEFAULT_PARAMS_FILE)
        change(doc["/**"]["ros__parameters"]["damper"]["adaptive"])
        with pytest.raises(ParameterError, match=words) as err:
            config_from_mapping(doc, "bad.yaml")
        assert "\n" not in str(err.value)
    doc = read_yaml(DEFAULT_PARAMS_FILE)
    doc["/**"]["ros__parameters"]["damper"]["adaptive"] = [1, 2]
    with pytest.raises(ParameterError, match=r"damper\.adaptive must be a mapping"):
        config_from_mapping(doc, "bad.yaml")


def test_replace_damper_validates_the_group(sport_cfg):
    bad = dataclasses.replace(sport_cfg.damper.adaptive, oil_density_kg_m3=-1.0)
    with pytest.raises(ParameterError, match=r"damper\.adaptive\.oil_density_kg_m3"):
        sport_cfg.replace_damper(adaptive=bad)


# --------------------------------------------------------------------------------------
# the emulator core passes the command on


def test_emulator_core_passes_the_valve_command(sport_model):
    from damper_emulator.realtime.core import EmulatorCore
    from damper_emulator.realtime.settings import (
        default_emulator_mapping,
        emulator_params_from_mapping,
    )

    params = emulator_params_from_mapping({**default_emulator_mapping(), "trigger": "input",
                                           "valve_command": 0.5}, "e.yaml")
    core = EmulatorCore(sport_model, params)
    assert core.stepper.valve_command == 0.5 and core.stepper.effective_valve_command == 0.5
    assert core.static_force_n == pytest.approx(sport_model.cfg.damper.static_force_n,
                                                rel=1e-9)
    assert core.set_valve_command(0.0) is None
    assert core.stepper.valve_command == 0.0
    assert core.set_valve_command(1.5) is not None and core.stepper.valve_command == 0.0
    # the core's model runs at that command (its first sample settles it, as a reset)
    ref = DamperStepper(sport_model, 0.0, 0.3, valve_command=0.0)
    out = [core.evaluate(k * 1_000_000, 0.0, 0.3) for k in range(50)]
    for k in range(1, 50):
        assert out[k].force_n == ref.step(0.0, 0.3, 1e-3)[0]
