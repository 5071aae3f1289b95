"""A test series through ``identify`` then ``diagnose``: a clean damper behind a rig that
hums and drifts is ``none`` with the rig's findings; a gas that leaks and an oil that warms
from file to file are the damper's drifts, named with their per-file values.  The truth
reaches the files through the rig (truth_series) and differs in form from the emulator's
model (smooth friction, displacement noise)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from diagnose_support import NOISE_N, PROTOCOL, identify_and_diagnose, pooled

from damper_emulator.diagnose.truth import REALISTIC, example_config, simulate_session
from damper_emulator.diagnose.truth_series import RigFaults, Series, gas_leak, series_starts
from damper_emulator.params import load_config

pytestmark = pytest.mark.slow

#: five files on the series clock 30 s apart (truth_series.Series' default gap)
FLAT_25_C = (25.0,) * 5
#: the candidates that took each series' change for the damper's before the series stage
#: existed (a thermal for the zero's drift, `other` for the leak), and the thermal one
#: beside the valve lag for the warming oil: each test checks the series stage, and the
#: full library runs in test_diagnose.py and the benchmark
CANDIDATES = {"rig": ["viscosity_temperature", "gas_heat_transfer", "valve_lag"],
              "leak": ["gas_heat_transfer", "viscosity_temperature"],
              "warm": ["viscosity_temperature", "valve_lag"]}


def session(series, effects=None, damper="sport", seed=11):
    sheet = load_config(f"config/{damper}.yaml")
    data = simulate_session(example_config(effects, sheet), PROTOCOL, noise_std_n=NOISE_N,
                            seed=seed, temperature=True, form=REALISTIC, series=series)
    return sheet, list(data.values())


def file_mean_times(data) -> list[float]:
    """Each file's mean time on the series clock, as truth_series lays the files out."""
    starts = series_starts([d.time[-1] - d.time[0] for d in data], Series().gap_s)
    return [s + float(np.mean(d.time - d.time[0])) for s, d in zip(starts, data)]


def test_a_clean_damper_behind_a_humming_drifting_rig_is_none_with_the_rigs_findings():
    """Mains hum (3 N at 50 Hz, 1 N at 150 Hz) and a load cell's zero drifting 0.3 N/s
    over the series, a thermocouple that reads a flat 25 °C: the answer is ``none``; the
    JSON's ``measurement`` names the line, the zero's offset per file (against the truth's
    drift between the files' mean times) and its drift within the files; no thermal
    candidate is tried (the temperature does not move)."""
    rate = 0.3
    faults = RigFaults(lines=((50.0, 3.0), (150.0, 1.0)), zero_offset_n=5.0,
                       zero_drift_n_per_s=rate)
    sheet, data = session(Series(faults=faults, oil_temperatures_c=FLAT_25_C))
    diag = identify_and_diagnose(sheet, data, CANDIDATES["rig"])
    doc = diag.to_json()
    assert diag.family == "none" and not diag.significant, doc["drift"]
    kinds = {f["kind"]: f for f in doc["measurement"]}
    assert {"interference", "zero_offset", "zero_drift"} <= set(kinds)
    lines = [f for f in doc["measurement"] if f["kind"] == "interference"]
    assert [round(f["value"]) for f in lines] == [50, 150]
    # the zero's offsets against the first file, as the truth drifted between files
    t_mean = file_mean_times(data)
    (zero,) = [d for d in doc["drift"] if d["kind"] == "zero"]
    # between the files after the first (the first, the reference, also holds the mains
    # aliased to a constant by its 50 Hz sampling, which no file can tell from its zero):
    # within 2 N (the chirp's drift within it is not fitted, its time being its speed)
    for (a, ta), (b, tb) in itertools.pairwise(zip(data[1:], t_mean[1:])):
        assert (zero["per_file"][b.name] - zero["per_file"][a.name]
                == pytest.approx(rate * (tb - ta), abs=2.0)), (a.name, b.name)
    # the drift within the files, weighted over them: the chirp's, most of the weight,
    # takes a little of the model's error that grows with the sweep
    assert kinds["zero_drift"]["value"] == pytest.approx(rate, rel=0.25)
    assert all(c["effect"] != "viscosity_temperature" for c in doc["candidates"])
    assert pooled(diag.rms_after, diag.held_out) < 2.0 * NOISE_N
    assert pooled(diag.rms_before, diag.held_out) > 3.0 * NOISE_N


def test_a_gas_charge_that_leaks_over_the_series_is_the_dampers_drift():
    """5 % of the charge lost with every file: ``gas_spring``, the charge per file within
    1 % of the truth's (the truth's reference charge is the data sheet's; the diagnosis
    reports against its own refit)."""
    sheet = load_config("config/sport.yaml")
    p0 = sheet.damper.gas_pressure_static_pa
    sheet, data = session(Series(changes=gas_leak(p0, 0.05)))
    diag = identify_and_diagnose(sheet, data, CANDIDATES["leak"])
    doc = diag.to_json()
    assert (diag.family, diag.effect) == ("gas_spring", "drift"), doc["drift"]
    (leak,) = doc["drift"]
    assert leak["parameter"] == "gas_pressure_static_pa" and leak["cause"] == "damper"
    ref = leak["reference_value"]
    for k, d in enumerate(data[1:], 1):
        # the ratio to the reference file's charge is the truth's
        assert leak["per_file"][d.name] / ref == pytest.approx(1.0 - 0.05 * k, rel=0.01)
    assert doc["measurement"] == [] or all(f["kind"] not in ("zero_offset", "gain")
                                           for f in doc["measurement"])
    assert pooled(diag.rms_after, diag.held_out) < 2.0 * NOISE_N


def test_an_oil_that_warms_over_the_series_without_a_thermocouple_is_thermal():
    """The oil 10 K warmer with every file, no temperature column: the valves' pressure
    drop per file follows the truth's viscosity law, ``s_k / s_j = exp(−β (T_k − T_j)/4)``
    (the library's thermal extension, β 0.03 /K)."""
    temps = (25.0, 35.0, 45.0, 55.0, 65.0)
    sheet, data = session(Series(oil_temperatures_c=temps, temperature_column=False),
                          effects="viscosity_temperature")
    assert all(d.temperature is None for d in data)
    diag = identify_and_diagnose(sheet, data, CANDIDATES["warm"])
    doc = diag.to_json()
    assert diag.family == "thermal", doc["drift"]
    (warm,) = [d for d in doc["drift"] if d["kind"] == "valve_scale"]
    beta = example_config("viscosity_temperature").damper.extensions \
        .viscosity_temperature.temperature_coefficient_per_k
    s = warm["per_file"]
    for d, t in zip(data[2:], temps[2:]):
        truth = math.exp(-beta * (t - temps[1]) / 4.0)
        assert s[d.name] / s[data[1].name] == pytest.approx(truth, rel=0.02), d.name
    assert pooled(diag.rms_after, diag.held_out) < 2.0 * NOISE_N
