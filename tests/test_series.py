"""What moves from file to file over a test series (damper_emulator.diagnose.series): the
selection on residuals made with known per-file values, and the rig-or-damper rule."""

from __future__ import annotations

import math

import numpy as np
import pytest

from damper_emulator.diagnose.series import KIND_BY_NAME, FileColumns, select, trend

NOISE_N = 4.0
NAMES = ("quasi_static.csv", "chirp.csv", "sine_1hz.csv", "sine_3hz.csv", "sine_12hz.csv")


def synthetic_series(seed=0, offsets=None, rates=None, gas=None, gain=None, n=3000):
    """Five files of a stroke ``x`` and a damping-like force, each residual white noise
    plus the given per-file offsets [N], drifts in time [N/s], gas changes [Pa] (a gas
    column ``A_rod (V/(V + A_rod x))^γ``, the sport damper's) and gains (times the
    force).  The first file is the reference: it has no offset, gas or gain column."""
    rng = np.random.default_rng(seed)
    a_rod, v_gas, gamma = 1.327e-4, 1.23e-4, 1.4
    files = []
    for k, name in enumerate(NAMES):
        t = np.linspace(0.0, 30.0, n)
        x = 0.05 * np.sin(2 * np.pi * (0.3 + 0.2 * k) * t)
        v = np.gradient(x, t)
        force = 3000.0 * v + 400.0 * np.tanh(v / 0.005) * 0.1
        gas_col = a_rod * (v_gas / (v_gas + a_rod * x)) ** gamma
        r = rng.normal(0.0, NOISE_N, n)
        if offsets is not None:
            r += offsets[k]
        if rates is not None:
            r += rates[k] * (t - t.mean())
        if gas is not None:
            r += gas[k] * gas_col
        if gain is not None:
            r += (gain[k] - 1.0) * force
        cols = {"zero_drift": t - t.mean()}
        if k:
            cols.update(zero=np.ones(n), gain=force, gas=gas_col,
                        friction=np.tanh(v / 0.005),
                        valve_scale=3000.0 * v)
        files.append(FileColumns(name, k >= 2, r, force, t, cols, NOISE_N))
    return files, {name: float(k) for k, name in enumerate(NAMES)}


def test_white_noise_moves_nothing():
    for seed in range(3):
        files, pos = synthetic_series(seed)
        assert select(files, pos).taken == [], seed


def test_a_zero_that_drifts_within_and_between_files_is_the_rigs():
    """Offsets of 0.3 N/s over files 30 s long, 30 s apart: each file's offset and its
    drift are the load cell's, with σ of least squares in white noise."""
    rate = 0.3
    offsets = [rate * 60.0 * k for k in range(5)]
    files, pos = synthetic_series(1, offsets=offsets, rates=[rate] * 5)
    result = select(files, pos)
    (zero,) = result.taken
    assert zero.kind.name == "zero" and zero.kind.cause == "rig"
    for k, name in enumerate(NAMES[1:], 1):
        assert zero.per_file[name] == pytest.approx(offsets[k], abs=4 * zero.std[name])
    for name in NAMES:
        assert zero.rates[name] == pytest.approx(rate, abs=4 * zero.rates_std[name])
    # the gas fitted the offsets too, but not the drift within the files
    tried = {t["kind"]: t for t in result.tried if t["round"] == 1}
    assert tried["zero"]["delta_bic"] < tried["gas"]["delta_bic"] - 10


def test_a_gas_charge_that_falls_with_every_file_is_the_dampers():
    """A 5 %-per-file leak of a 3 MPa charge: per-file changes on a line over the series;
    no drift within the files, so the zero's columns cost it the comparison."""
    gas = [-0.05 * 3.0e6 * k for k in range(5)]
    files, pos = synthetic_series(2, gas=gas)
    result = select(files, pos)
    (leak,) = result.taken
    assert leak.kind.name == "gas" and leak.kind.family == "gas_spring"
    for k, name in enumerate(NAMES[1:], 1):
        assert leak.per_file[name] == pytest.approx(gas[k], abs=4 * leak.std[name])
    assert leak.r2 > 0.99
    assert leak.slope == pytest.approx(-0.05 * 3.0e6, rel=0.05)


def test_a_damper_parameter_that_jumps_about_is_not_taken():
    """Per-file friction changes of ±30 N in no order: the model's error at each file's
    speeds, not a drift of the seal; a rig's gain of the same pattern would be taken."""
    files, pos = synthetic_series(3)
    jumps = [0.0, 30.0, -30.0, 30.0, -30.0]
    for fc, j in zip(files, jumps):
        if "friction" in fc.columns:
            fc.residual = fc.residual + j * fc.columns["friction"]
    result = select(files, pos, kinds=["friction"])
    assert result.taken == []
    (tried,) = result.tried
    assert tried["delta_bic"] < -10 and not tried["consistent"]


@pytest.mark.parametrize("gain", [(1.0, 1.01, 1.02, 1.03, 1.04),   # an amplifier warming
                                  (1.0, 1.03, 1.03, 1.03, 1.03)])  # one gain, off
def test_a_gain_that_drifts_or_is_one_of_the_series_is_the_rigs(gain):
    files, pos = synthetic_series(4, gain=gain)
    (g,) = select(files, pos).taken
    assert g.kind.name == "gain" and g.kind.cause == "rig"
    values = g.values()
    for k, name in enumerate(NAMES[1:], 1):
        assert values[name] == pytest.approx(gain[k], abs=4 * g.std[name])


def test_a_gain_that_jumps_from_file_to_file_is_not_taken():
    """±3 % from one file to the next: no load cell does that; a per-file gain that does
    takes a share of something the model lacks."""
    files, pos = synthetic_series(4, gain=(1.0, 1.03, 0.97, 1.03, 0.97))
    result = select(files, pos, kinds=["gain"])
    assert result.taken == []
    (tried,) = result.tried
    assert tried["delta_bic"] < -10 and not tried["consistent"]


def test_the_trend_is_weighted_least_squares():
    """A line through exact points: the slope, and R² = 1; a value off the line lowers
    R² by its share of the weighted sum of squares."""
    slope, sd, r2, _, _ = trend([0, 1, 2, 3], [1.0, 3.0, 5.0, 7.0], [0.1] * 4)
    assert slope == pytest.approx(2.0) and r2 == pytest.approx(1.0)
    assert sd == pytest.approx(math.sqrt(1.0 / (5.0 / 0.01)))
    r2 = trend([0, 1, 2, 3], [1.0, 3.0, 5.0, 9.0], [1.0] * 4).r2
    y = np.array([1.0, 3.0, 5.0, 9.0])
    fitted = np.polyval(np.polyfit([0, 1, 2, 3], y, 1), [0, 1, 2, 3])
    assert r2 == pytest.approx(1 - np.sum((y - fitted) ** 2) / np.sum((y - y.mean()) ** 2))


def test_the_kinds_name_their_parameters_and_causes():
    assert KIND_BY_NAME["zero"].cause == "rig" and KIND_BY_NAME["gain"].cause == "rig"
    assert {KIND_BY_NAME[k].family for k in ("gas", "friction", "valve_scale")} == {
        "gas_spring", "friction", "thermal"}


def test_a_series_run_slowest_first_is_ordered_by_speed():
    """A peak-velocity series run slowest first: what changes over it changes with the
    speed too; the same files in another order are not."""
    from damper_emulator.diagnose.base import make_record
    from damper_emulator.diagnose.series import speed_ordered
    from damper_emulator.dyno.measured import MeasuredData

    t = np.linspace(0.0, 2.0, 2001)
    recs = [make_record(MeasuredData(t, 0.025 * np.sin(2 * np.pi * f * t),
                                     np.zeros_like(t), name=f"speed_{k}.csv"), False)
            for k, f in enumerate((0.5, 1.0, 2.0, 4.0, 8.0))]
    by_index = {r.name: float(k) for k, r in enumerate(recs)}
    assert speed_ordered(recs, by_index)
    mixed = dict(zip([r.name for r in recs], (2.0, 0.0, 4.0, 1.0, 3.0)))
    assert not speed_ordered(recs, mixed)
