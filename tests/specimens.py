"""Specimens for a virtual rig that are not the twin (a real damper never equals its
model)."""

from __future__ import annotations

import dataclasses

from damper_emulator.params import ModelConfig, load_config, with_extensions


def mismatched_specimen() -> ModelConfig:
    """A specimen that is not the sport twin: its valves (rebound preload 0.7×, port 1.6×;
    compression spring 1.5×), a seventh of the oil's compressibility, a LuGre friction
    and an oil that thins as the tests warm it, none of which the twin has."""
    cfg = load_config()
    d = cfg.damper
    damper = dataclasses.replace(
        d, friction_force_n=70.0, oil_compressibility_per_pa=2e-10,
        rebound=dataclasses.replace(d.rebound, preload_pa=0.7 * d.rebound.preload_pa,
                                    k_port=1.6 * d.rebound.k_port),
        compression=dataclasses.replace(d.compression, k_spring=1.5 * d.compression.k_spring))
    return with_extensions(dataclasses.replace(cfg, damper=damper), {
        "lugre_friction": {"coulomb_n": 70.0, "static_n": 110.0,
                           "stribeck_velocity_m_s": 0.01, "bristle_stiffness_n_m": 2e5},
        "viscosity_temperature": {"temperature_coefficient_per_k": 0.02,
                                  "reference_temperature_c": 25.0,
                                  "heat_capacity_j_per_k": 400.0,
                                  "cooling_time_constant_s": 600.0}})
