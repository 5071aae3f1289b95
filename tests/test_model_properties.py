"""Property tests over valid parameter ranges (hypothesis)."""

import dataclasses
import math

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from damper_emulator.dyno.protocols import sine
from damper_emulator.model.compressible import DamperModel, DamperStepper, simulate
from damper_emulator.model.incompressible import incompressible_force
from damper_emulator.params import ModelConfig, ValveParams, load_config, validate
from damper_emulator.schema import ParameterError

SPORT = load_config()
SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def _factor(draw, decades):
    return 10.0 ** draw(st.floats(-decades, decades))


@st.composite
def valves(draw, base: ValveParams):
    return ValveParams(k_leak=base.k_leak * _factor(draw, 1.0),
                       k_port=base.k_port * _factor(draw, 1.0),
                       k_spring=base.k_spring * _factor(draw, 1.0),
                       preload_pa=base.preload_pa * _factor(draw, 0.5),
                       smoothing_g=draw(st.floats(1.2, 3.0)))


@st.composite
def configs(draw):
    d = SPORT.damper
    piston = draw(st.floats(0.025, 0.050))
    damper = dataclasses.replace(
        d,
        pressure_tube_length_m=draw(st.floats(0.30, 0.60)),
        x0_m=draw(st.floats(0.05, 0.20)),
        piston_diameter_m=piston,
        rod_diameter_m=draw(st.floats(0.008, piston - 0.008)),
        gas_gamma=draw(st.floats(1.0, 1.4)),
        oil_kinematic_viscosity_m2_s=d.oil_kinematic_viscosity_m2_s * _factor(draw, 0.5),
        oil_compressibility_per_pa=draw(st.floats(1e-10, 5e-9)),
        friction_force_n=draw(st.floats(0.0, 200.0)),
        gas_volume_static_m3=draw(st.floats(3e-5, 3e-4)),
        gas_pressure_static_pa=draw(st.floats(0.5e6, 5e6)),
        rebound=draw(valves(d.rebound)),
        compression=draw(valves(d.compression)),
    )
    cfg = ModelConfig(damper, dataclasses.replace(SPORT.numerics, valve_table_points=256),
                      "hypothesis")
    try:
        validate(cfg)
    except ParameterError:
        assume(False)  # a non-invertible valve is refused at load; not a valid parameter set
    return cfg


@SETTINGS
@given(cfg=configs(), f_hz=st.floats(0.2, 25.0), v_peak=st.floats(0.01, 3.0))
def test_compressible_force_is_never_nan(cfg, f_hz, v_peak):
    d = cfg.damper
    amp = min(v_peak / (2 * math.pi * f_hz), 0.5 * d.max_extension_m,
              0.5 * d.max_compression_m)
    t, x, v = sine(f_hz, amp, cycles=2, rate_hz=1000)
    model = DamperModel(cfg)
    r = simulate(model, t, x, v)
    assert np.all(np.isfinite(r.force_n))
    assert np.all(np.isfinite(r.rebound_pressure_pa))


@SETTINGS
@given(cfg=configs(), data=st.data())
def test_stepper_output_is_finite_for_any_input(cfg, data):
    stepper = DamperStepper(DamperModel(cfg))
    numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                        st.floats(-1.0, 1.0), st.floats(-5.0, 5.0))
    for _ in range(30):
        x, v = data.draw(numbers), data.draw(numbers)
        dt = data.draw(st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                                 st.floats(1e-5, 2e-2)))
        force, _ = stepper.step(x, v, dt)
        assert math.isfinite(force)


@SETTINGS
@given(cfg=configs())
def test_incompressible_force_is_monotonic_in_velocity(cfg):
    v = np.concatenate((-np.geomspace(3.0, 1e-6, 3000), [0.0], np.geomspace(1e-6, 3.0, 3000)))
    force = incompressible_force(v, cfg)
    assert np.all(np.isfinite(force))
    assert np.all(np.diff(force) > 0)
