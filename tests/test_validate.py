"""Validation of the compressible model against measured data (docs/model.md §3, eqs 34–35) and
the ``damper-hil validate`` command line (docs/interfaces.md §3).

Reference data come from the virtual dyno; the expectations are independent of the
validator: the force noise the dyno added (its r.m.s. is the noise's standard deviation)
and, for a friction force off by ``ΔF``, the closed form ``ΔF · √(mean(sgn(ẋ)²))``: in
eq 4 friction only adds ``F_friction sgn ẋ`` to the force, it does not enter the
pressures, so the force error is that constant-magnitude square wave.
"""

import json
import math

import numpy as np
import pytest

from damper_emulator.dyno import runner
from damper_emulator.dyno.measured import MeasuredData, write_measured_csv
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import DEFAULT_PARAMS_FILE
from damper_emulator.validation import (
    dominant_frequency,
    estimate_velocity,
    savgol_window,
    validate_file,
)
from damper_hil.cli import main


def dyno_sine(model, frequency, amplitude, cycles=3, rate=1000.0, noise_std=0.0, seed=0,
              with_velocity=True, name="sine.csv"):
    t, x, v, f, _ = runner.simulate_sine(model, frequency, amplitude, cycles, rate, 1)
    if noise_std:
        f = f + np.random.default_rng(seed).normal(0.0, noise_std, f.size)
    return MeasuredData(time=t, displacement=x, force=f,
                        velocity=v if with_velocity else None, name=name)


@pytest.fixture(scope="module")
def sine_3hz(sport_model):
    return dyno_sine(sport_model, 3.0, 0.05, name="sine_3hz.csv")


# --------------------------------------------------------------------------------------
# validate_file


def test_same_parameters_noise_free_match(sport_model, sine_3hz):
    r = validate_file(sport_model, sine_3hz)
    assert r["samples"] == sine_3hz.time.size
    assert r["velocity_source"] == "file"
    # the only difference is the quasi-steady start (a few ms of pressure transient)
    assert r["relative_rms"] < 1e-3
    rms_meas = math.sqrt(np.mean(sine_3hz.force ** 2))
    assert r["rms_measured_N"] == pytest.approx(rms_meas, rel=1e-12)
    assert r["relative_rms"] == pytest.approx(r["rms_N"] / rms_meas, rel=1e-12)
    assert r["peak_force_measured_rebound_n"] == pytest.approx(sine_3hz.force.max())
    assert r["peak_force_simulated_compression_n"] == pytest.approx(
        sine_3hz.force.min(), abs=5.0)
    s = r["series"]
    assert s["force_simulated"].shape == s["force_measured"].shape == sine_3hz.time.shape
    assert r["faults"] == []


def test_noise_is_what_remains(sport_model):
    noise = 4.0
    data = dyno_sine(sport_model, 3.0, 0.05, noise_std=noise, seed=7)
    r = validate_file(sport_model, data)
    assert r["rms_N"] == pytest.approx(noise, rel=0.10)


def test_friction_off_by_100_n_gives_100_n(sport_model, sport_cfg, sine_3hz):
    wrong = DamperModel(sport_cfg.replace_damper(
        friction_force_n=sport_cfg.damper.friction_force_n + 100.0))
    r = validate_file(wrong, sine_3hz)
    sgn = np.sign(sine_3hz.velocity)
    expected = 100.0 * math.sqrt(np.mean(sgn ** 2))
    assert r["rms_N"] == pytest.approx(expected, rel=0.01)
    # the error is the right model's (start transient only) + 100 N sgn ẋ
    right = validate_file(sport_model, sine_3hz)
    extra = r["series"]["force_simulated"] - right["series"]["force_simulated"]
    assert np.allclose(extra, 100.0 * sgn, rtol=0.0, atol=1e-6)


def test_velocity_estimated_when_the_file_has_none(sport_model):
    # 1.7 Hz: no sample falls exactly on a velocity reversal (there sgn ẋ of the exact
    # and of any estimated velocity may differ, a 2 F_friction jump on one sample)
    data = dyno_sine(sport_model, 1.7, 0.05, cycles=2, with_velocity=False)
    r = validate_file(sport_model, data)
    assert r["velocity_source"] == "savgol"
    assert r["dominant_frequency_hz"] == pytest.approx(1.7, rel=0.05)
    assert r["relative_rms"] < 1e-3


def test_history_beyond_travel_names_the_file(sport_model):
    t = np.linspace(0.0, 1.0, 101)
    data = MeasuredData(time=t, displacement=0.5 * t, force=np.zeros_like(t),
                        name="far.csv", path="data/far.csv")
    with pytest.raises(ValueError, match=r"^data/far\.csv: cannot simulate .*travel"):
        validate_file(sport_model, data)


# --------------------------------------------------------------------------------------
# velocity estimate


def test_savgol_velocity_of_a_sine():
    rate, f, a = 1000.0, 3.0, 0.05
    t = np.arange(0, 2001) / rate
    x = a * np.sin(2 * np.pi * f * t)
    v, how = estimate_velocity(t, x)
    assert how["savgol_window"] == 17  # 1/20 of 333 samples, odd
    assert how["dominant_frequency_hz"] == pytest.approx(f, rel=0.01)
    exact = a * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    assert np.abs(v - exact).max() < 1e-4 * a * 2 * np.pi * f


def test_savgol_velocity_non_uniform_sampling():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 3000))
    x = 0.02 * np.sin(2 * np.pi * 2.0 * t)
    v, how = estimate_velocity(t, x)
    assert how["resampled"] is True
    exact = 0.02 * 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t)
    assert np.abs(v - exact).max() < 1e-3 * 0.02 * 2 * np.pi * 2.0


def test_window_limits():
    assert savgol_window(1000.0, 12.0, 1000) == 5      # 4.2 samples → the minimum
    assert savgol_window(1000.0, 1.0, 1000) == 51
    assert savgol_window(1000.0, 0.01, 1000) == 999    # capped at the data, odd
    assert savgol_window(1000.0, math.nan, 1000) == 5
    assert math.isnan(dominant_frequency(np.arange(3.0), np.zeros(3)))


# --------------------------------------------------------------------------------------
# command line


@pytest.fixture(scope="module")
def sine_files(sport_model, tmp_path_factory):
    d = tmp_path_factory.mktemp("val")
    paths = []
    for freq, amp, noise in ((3.0, 0.05, 4.0), (12.0, 0.005, 0.0)):
        t, x, v, f, _ = runner.simulate_sine(sport_model, freq, amp, 2, 1000.0, 1)
        f = f + np.random.default_rng(1).normal(0.0, noise, f.size) if noise else f
        paths.append(write_measured_csv(d / runner.sine_file_name(freq), t, x, f,
                                        velocity=v))
    return paths


def test_cli_writes_contract_json_and_report(sine_files, tmp_path, capsys):
    out_json, report = tmp_path / "res" / "val.json", tmp_path / "report"
    rc = main(["validate", "--params", str(DEFAULT_PARAMS_FILE), *map(str, sine_files),
               "--json", str(out_json), "--report", str(report)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    doc = json.loads(out_json.read_text())
    assert set(doc) == {"params_file", "files", "acquisition"}
    assert doc["acquisition"] == {"source": "none", "rig": None, "force_delay_s": 0.0}
    assert set(doc["files"]) == {"sine_3hz.csv", "sine_12hz.csv"}
    for entry in doc["files"].values():
        assert isinstance(entry["rms_N"], float) and isinstance(entry["relative_rms"], float)
    assert doc["files"]["sine_3hz.csv"]["rms_N"] == pytest.approx(4.0, rel=0.15)
    assert doc["files"]["sine_12hz.csv"]["relative_rms"] < 1e-3
    for name in ("validate_sine_3hz.png", "validate_sine_12hz.png",
                 "validation_summary.png"):
        assert (report / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "[1/2] validating sine_3hz.csv" in cap.err
    assert f"wrote {out_json}" in cap.err.splitlines()
    assert "sine_12hz.csv" in cap.out  # the table


def test_cli_default_json_location(sine_files, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["validate", "--params", str(DEFAULT_PARAMS_FILE), str(sine_files[1])]) == 0
    assert "sine_12hz.csv" in json.loads((tmp_path / "validation.json").read_text())["files"]
    assert main(["validate", "--params", str(DEFAULT_PARAMS_FILE), str(sine_files[1]),
                 "--report", "rep"]) == 0
    assert (tmp_path / "rep" / "validation.json").is_file()
    capsys.readouterr()


@pytest.mark.parametrize(("content", "problem"), [
    ("time,force\n0,1\n0.001,2\n", "missing required column 'displacement'"),
    ("time,displacement,force\n0,0,1\n0.001,nan,2\n", "row 2"),
    ("time,displacement,force\n0,0,1\n0,0.001,2\n", "time is not strictly increasing"),
])
def test_cli_bad_file_one_line_exit_2(sine_files, tmp_path, capsys, content, problem):
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    rc = main(["validate", "--params", str(DEFAULT_PARAMS_FILE), str(sine_files[1]),
               str(bad), "--json", str(tmp_path / "v.json")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("damper-hil: error: ")
    assert str(bad) in err and problem in err
    assert not (tmp_path / "v.json").exists()  # nothing half-written


def test_cli_duplicate_base_names(sine_files, tmp_path, capsys):
    other = tmp_path / "x" / sine_files[1].name
    other.parent.mkdir()
    other.write_bytes(sine_files[1].read_bytes())
    rc = main(["validate", "--params", str(DEFAULT_PARAMS_FILE), str(sine_files[1]),
               str(other)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "base name" in err


# --------------------------------------------------------------------------------------
# wrong units of force and time (docs/interfaces.md §2: refused with one line naming file and row)


def _rewritten(src, dest, time_factor=1.0, force_factor=1.0, velocity=True):
    """``src`` written again with its time and force multiplied by the given factors."""
    from damper_emulator.dyno.measured import read_measured_csv

    d = read_measured_csv(src)
    return write_measured_csv(dest, d.time * time_factor, d.displacement,
                              d.force * force_factor,
                              velocity=d.velocity if velocity else None), d


def _refused(tmp_path, capsys, bad, needle, row):
    rc = main(["validate", "--params", str(DEFAULT_PARAMS_FILE), str(bad),
               "--json", str(tmp_path / "v.json")])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("damper-hil: error: "), err
    assert str(bad) in err and f"row {row} " in err and needle in err, err
    assert not (tmp_path / "v.json").exists()


@pytest.mark.parametrize("velocity", [True, False])
def test_cli_refuses_force_in_kilonewtons(sine_files, tmp_path, capsys, velocity):
    # the 3 Hz sine's force in kN; the error names the row of the peak |force|
    bad, d = _rewritten(sine_files[0], tmp_path / "kn.csv", force_factor=1e-3,
                        velocity=velocity)
    _refused(tmp_path, capsys, bad, "looks like kilonewtons; expected newtons",
             int(np.argmax(np.abs(d.force))) + 1)


def test_cli_refuses_force_in_kilonewtons_of_a_heavy_damper(sine_files, tmp_path, capsys):
    # a damper ten times as strong (peak 26 kN, more than the 20 N floor in kN): its force
    # per unit speed in kN, about 28, is not a damper's (hundreds of N·s/m and more)
    bad, d = _rewritten(sine_files[0], tmp_path / "heavy_kn.csv", force_factor=1e-2)
    assert np.abs(d.force).max() * 1e-2 > 20.0
    _refused(tmp_path, capsys, bad, "N·s/m", int(np.argmax(np.abs(d.force))) + 1)


@pytest.mark.parametrize("velocity", [True, False])
def test_cli_refuses_time_in_milliseconds(sine_files, tmp_path, capsys, velocity):
    # 1 kHz in ms: 1 per step; the first step ends on data row 2
    bad, _ = _rewritten(sine_files[1], tmp_path / "ms.csv", time_factor=1e3,
                        velocity=velocity)
    _refused(tmp_path, capsys, bad, "looks like milliseconds; expected seconds", 2)


def test_cli_refuses_time_in_ms_of_a_fast_short_file_by_its_velocity(sport_model, tmp_path,
                                                                       capsys):
    # 20 kHz for 0.5 s in ms: steps of 0.05 and 500 "s" in all look plausible, but the
    # velocity column is 1000 × d(displacement)/d(time); the row is the peak velocity's
    t, x, v, f, _ = runner.simulate_sine(sport_model, 12.0, 0.005, 6, 20_000.0, 1)
    bad = write_measured_csv(tmp_path / "fast_ms.csv", t * 1e3, x, f, velocity=v)
    _refused(tmp_path, capsys, bad, "milliseconds", int(np.argmax(np.abs(v))) + 1)


def test_cli_accepts_quasi_static_at_50_hz_over_150_s(sport_model, tmp_path, capsys):
    # the slowest legitimate file of the project: 4 mm/s, 0.02 s steps, 150 s, 300–500 N
    runner.run_quasi_static(sport_model, tmp_path)
    rc = main(["validate", "--params", str(DEFAULT_PARAMS_FILE),
               str(tmp_path / "quasi_static.csv"), "--json", str(tmp_path / "v.json")])
    err = capsys.readouterr().err
    assert rc == 0, err
    doc = json.loads((tmp_path / "v.json").read_text())
    assert doc["files"]["quasi_static.csv"]["samples"] == 7501


def test_cli_refuses_quasi_static_force_in_kilonewtons(sport_model, tmp_path, capsys):
    # at 4 mm/s the force is gas and friction (0.3–0.5 kN) and the speed too low to judge
    # damping: the peak alone (0.5 while the rod strokes 150 mm) gives the kN away
    runner.run_quasi_static(sport_model, tmp_path)
    bad, d = _rewritten(tmp_path / "quasi_static.csv", tmp_path / "qs_kn.csv",
                        force_factor=1e-3)
    _refused(tmp_path, capsys, bad, "while the displacement moves 150 mm",
             int(np.argmax(np.abs(d.force))) + 1)


def test_reader_accepts_a_rod_at_rest_with_a_tared_load_cell(tmp_path):
    # no stroke (< 1 mm): a force near 0 N is no sign of kilonewtons
    from damper_emulator.dyno.measured import read_measured_csv

    t = np.arange(0, 1.0, 1e-3)
    path = write_measured_csv(tmp_path / "rest.csv", t, 1e-5 * np.sin(50 * t),
                              0.5 * np.cos(50 * t))
    assert len(read_measured_csv(path)) == t.size
