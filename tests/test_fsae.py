"""FSAE TTX25 vendor dyno files: reader, conventions, file names, export
(damper_emulator/dyno/fsae.py; docs/measured/fsae_ttx25_data.md).

The real files are read from ``../shared/data/measured/fsae_ttx25`` next to the repository
and never copied into it; the tests that need them skip when that folder is absent. The
synthetic-file tests always run.
"""

import dataclasses
import gzip
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from damper_emulator.dyno.fsae import (
    FORCE_N_PER_V,
    STROKE_M,
    FsaeRunInfo,
    cycle_starts,
    cycle_work,
    export_fsae_csv,
    fsae_files,
    parse_fsae_name,
    read_fsae_ttx25,
)
from damper_emulator.dyno.measured import MeasuredDataError, read_measured_csv

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "measured" / "fsae_ttx25"
HEADER = ("Timestamp,Force (V),Force (N),Displacement (V),Displacement (mm),"
          "Temperature (V),Temperature (C)")


@pytest.fixture(scope="module")
def runs():
    """``{relative path: MeasuredData}`` of every real file (skips when absent)."""
    if not DATA.is_dir():
        pytest.skip(f"FSAE data folder absent: {DATA}")
    files = fsae_files(DATA)
    if not files:
        pytest.skip(f"no FSAE files under {DATA}")
    return {str(p.relative_to(DATA)): read_fsae_ttx25(p) for p in files}


# --------------------------------------------------------------------------------------
# real files


def test_all_fourteen_files_are_found(runs):
    top = [k for k in runs if "/" not in k]
    sub = [k for k in runs if k.startswith("pressure_testing/")]
    assert len(top) == 6 and len(sub) == 8, sorted(runs)


def test_time_strictly_increasing_from_zero_at_300_hz(runs):
    for name, d in runs.items():
        assert d.time[0] == 0.0, name
        assert np.all(np.diff(d.time) > 0), name
        rate = (len(d) - 1) / d.duration_s
        assert rate == pytest.approx(300.0, rel=0.01), (name, rate)


def test_positive_dissipation_on_every_cycle(runs):
    """∮F dx > 0 (force rebound +, displacement extension +) on every full cycle."""
    for name, d in runs.items():
        info = parse_fsae_name(name)
        w = cycle_work(d)
        assert len(w) >= info.cycles - 1, (name, len(w))
        assert np.all(w > 0), (name, w.min())
        # clear of noise: the smallest cycle is within 10 % of the file's mean
        assert w.min() > 0.9 * w.mean(), (name, w.min(), w.mean())


def test_stroke_is_the_rigs_38_mm(runs):
    for name, d in runs.items():
        stroke = d.displacement.max() - d.displacement.min()
        assert stroke == pytest.approx(STROKE_M, rel=0.10), (name, stroke)
        # the reference is mid-stroke: the extremes are symmetric about zero
        assert abs(d.displacement.max() + d.displacement.min()) < 0.5e-3, name


def test_gas_force_is_compressive_and_scales_with_the_charge(runs):
    """The force-sign evidence: on the slow runs the mid-stroke average of the two strokes
    (static gas force, friction cancels) is negative and proportional to the charge."""

    def static(d):
        x, v, f = d.displacement, d.velocity, d.force
        mid = np.abs(x) < 0.5e-3
        return 0.5 * (np.median(f[mid & (v > 0)]) + np.median(f[mid & (v < 0)]))

    f100 = static(runs["pressure_testing/t1_1_1_18_18_s1_n10_100psi.csv.gz"])
    f150 = static(runs["pressure_testing/t1_1_1_18_18_s1_n10_150psi.csv.gz"])
    assert f100 < -15 and f150 < -15
    assert f150 / f100 == pytest.approx(1.5, rel=0.1)


def test_velocity_is_the_derivative_of_displacement(runs):
    d = runs["pressure_testing/t1_1_1_18_18_s6_n10_100psi.csv.gz"]
    peak = np.abs(d.velocity).max()
    assert 0.13 < peak < 0.17  # s6: about 150 mm/s
    # integrating the velocity gives back the displacement to a small fraction of the stroke
    x = d.displacement[0] + np.concatenate(
        [[0.0], np.cumsum(0.5 * (d.velocity[1:] + d.velocity[:-1]) * np.diff(d.time))])
    assert np.max(np.abs(x - d.displacement)) < 0.01 * STROKE_M


def test_temperature_is_plausible_celsius(runs):
    for name, d in runs.items():
        assert 15.0 < np.median(d.temperature) < 90.0, name


def test_every_real_file_name_parses(runs):
    for name in runs:
        info = parse_fsae_name(name)
        assert info.speed_code in (1, 5, 6) and info.gas_psi in (50, 100, 150), name
        assert info.cycles in (10, 100) and info.heat_gun == ("heat_gun" in name), name


def test_export_round_trips_through_the_contract_reader(runs, tmp_path):
    d = runs["pressure_testing/t1_1_1_18_18_s6_n10_100psi.csv.gz"]
    out = export_fsae_csv(d, tmp_path / "export")
    assert out == tmp_path / "export" / "t1_1_1_18_18_s6_n10_100psi.csv"
    back = read_measured_csv(out)
    for col in ("time", "displacement", "velocity", "force", "temperature"):
        np.testing.assert_allclose(getattr(back, col), getattr(d, col), rtol=1e-7,
                                   atol=1e-12, err_msg=col)


@pytest.mark.slow
def test_every_exported_run_passes_the_unit_checks_and_fails_them_in_kn_and_ms(runs,
                                                                               tmp_path):
    """The contract reader's plausibility checks (force in kN, time in ms) accept every
    real run, the slow s1 runs with their 75–90 N peaks included, and refuse each run
    written in kN or in ms."""
    from damper_emulator.dyno.measured import write_measured_csv

    for d in runs.values():
        read_measured_csv(export_fsae_csv(d, tmp_path / "ok"))  # raises if refused
        for unit, time_s, force_n in (("kilonewtons", d.time, d.force * 1e-3),
                                      ("milliseconds", d.time * 1e3, d.force)):
            path = write_measured_csv(tmp_path / f"wrong_{unit}.csv", time_s,
                                      d.displacement, force_n, velocity=d.velocity,
                                      temperature=d.temperature)
            with pytest.raises(MeasuredDataError, match=f"looks like {unit}"):
                read_measured_csv(path)


# --------------------------------------------------------------------------------------
# file names


def test_parse_fsae_name_fields():
    info = parse_fsae_name("some/dir/t2_3_3_24_24_s5_n100_100psi_with_heat_gun.csv.gz")
    assert info == FsaeRunInfo(name="t2_3_3_24_24_s5_n100_100psi_with_heat_gun", trial=2,
                               valves=(3, 3, 24, 24), speed_code=5, cycles=100,
                               gas_psi=100.0, heat_gun=True)
    assert info.valve_label == "3_3_24_24"
    assert info.gas_pressure_pa == pytest.approx(689476, rel=1e-5)
    assert info.nominal_frequency_hz == pytest.approx(1.05)
    info = parse_fsae_name("t1_1_1_18_18_s1_n10_150psi.csv")
    assert (info.trial, info.valves, info.speed_code, info.cycles, info.gas_psi,
            info.heat_gun) == (1, (1, 1, 18, 18), 1, 10, 150.0, False)


@pytest.mark.parametrize("bad", ["t1_1_1_18_s1_n10_150psi.csv.gz", "sine_3hz.csv",
                                 "t1_1_1_18_18_s1_n10_150.csv.gz",
                                 "t1_1_1_18_18_s1_n10_150psi_extra.csv.gz"])
def test_parse_fsae_name_rejects_other_names(bad):
    with pytest.raises(ValueError, match="not an FSAE run name"):
        parse_fsae_name(bad)


# --------------------------------------------------------------------------------------
# synthetic vendor files


def vendor_file(path: Path, n=600, fs=300.0, f0=1.0, mutate=None) -> Path:
    """A well-formed synthetic vendor file: pot 31.35 ± 18.6 mm sine, force −100 N·v-ish."""
    t0 = datetime(2025, 11, 14, 20, 7, 10, 531160)
    lines = [HEADER]
    for i in range(n):
        t = i / fs
        mm = 31.35 + 18.6 * np.sin(2 * np.pi * f0 * t)
        fv = -0.5 * np.cos(2 * np.pi * f0 * t)  # rebound (−V) while the pot increases
        stamp = (t0 + timedelta(seconds=t)).isoformat(sep=" ")
        row = [stamp] + [repr(float(a)) for a in (fv, -FORCE_N_PER_V * fv, mm / 9.64, mm)]
        row += ["1.0", "25.0"]
        if mutate:
            row = mutate(i, row)
        lines.append(",".join(row))
    with gzip.open(path, "wt", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    return path


def test_synthetic_file_conversion(tmp_path):
    p = vendor_file(tmp_path / "t1_1_1_18_18_s5_n10_100psi.csv.gz", n=700)
    d = read_fsae_ttx25(p)
    t = np.arange(700) / 300.0
    np.testing.assert_allclose(d.time, t, atol=1e-6)
    np.testing.assert_allclose(d.displacement, 18.6e-3 * np.sin(2 * np.pi * t), atol=2e-6)
    np.testing.assert_allclose(d.force, FORCE_N_PER_V * 0.5 * np.cos(2 * np.pi * t), rtol=1e-9)
    np.testing.assert_allclose(d.velocity, 2 * np.pi * 18.6e-3 * np.cos(2 * np.pi * t),
                               atol=2e-4)
    assert np.all(d.temperature == 25.0)
    assert d.name == p.name and d.path == str(p)
    w = cycle_work(d, cycle_starts(d))
    # upward mid-stroke crossings at 1 s and 2 s (not at t = 0: nothing below before it)
    np.testing.assert_array_equal(cycle_starts(d), [300, 600])
    # force in phase with velocity: dissipative, W = π c ω X² with c = 99.19 / (2π·18.6e-3)
    assert len(w) == 1
    assert w[0] == pytest.approx(np.pi * 0.5 * FORCE_N_PER_V * 18.6e-3, rel=1e-3)


@pytest.mark.parametrize(("mutate", "row", "what"), [
    (lambda i, r: ([r[0] if i != 3 else "2025-11-14 20:07:10.531160", *r[1:]]), 4,
     "time is not strictly increasing"),
    (lambda i, r: ([*r[:1], "abc", *r[2:]]) if i == 6 else r, 7, "Force (V) is 'abc'"),
    (lambda i, r: (["yesterday", *r[1:]]) if i == 2 else r, 3, "not an ISO date-time"),
    (lambda i, r: ([*r[:3], "nan", *r[4:]]) if i == 9 else r, 10, "Displacement (V) is nan"),
    (lambda i, r: r[:3] if i == 11 else r, 12, "no value for column"),
])
def test_malformed_vendor_file_names_file_and_row(tmp_path, mutate, row, what):
    p = vendor_file(tmp_path / "bad.csv.gz", mutate=mutate)
    with pytest.raises(MeasuredDataError) as exc:
        read_fsae_ttx25(p)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(f"{p}: row {row} (line {row + 1}): ")
    assert what in msg


def test_vendor_file_missing_column_or_empty(tmp_path):
    p = tmp_path / "nocol.csv"
    p.write_text("Timestamp,Force (V),Temperature (C)\n2025-11-14 20:07:10,0.1,25\n")
    with pytest.raises(MeasuredDataError, match=r"nocol\.csv: header: missing required column "
                                                r"'Displacement \(V\)'"):
        read_fsae_ttx25(p)
    e = tmp_path / "empty.csv.gz"
    with gzip.open(e, "wt") as fh:
        fh.write("")
    with pytest.raises(MeasuredDataError, match="empty file"):
        read_fsae_ttx25(e)
    with pytest.raises(MeasuredDataError, match="cannot read"):
        read_fsae_ttx25(tmp_path / "absent.csv.gz")


def test_a_column_map_alone_reads_every_top_level_run_as_the_fsae_reader(runs):
    """issue: the FSAE runs go through identify and diagnose with a map alone.  The map
    (the vendor's converted columns, its ISO stamps, mid-stroke zero, the reader's
    velocity filter) gives the same arrays, bit for bit, where Force (N) is the
    rebound-positive one (the top-level files); in pressure_testing/ its slope has the
    other sign, and the energy check refuses it, naming --force-sign -1."""
    from damper_emulator.dyno.column_map import ColumnMap, read_mapped_csv

    cmap = ColumnMap(columns={"time": "Timestamp", "displacement": "Displacement (mm)",
                              "force": "Force (N)", "temperature": "Temperature (C)"},
                     displacement_zero="mid-stroke", velocity_window=25)
    top = [k for k in runs if "/" not in k]
    assert top
    for name in top:
        mapped, reader = read_mapped_csv(DATA / name, cmap), runs[name]
        for q in ("time", "displacement", "force", "velocity", "temperature"):
            np.testing.assert_array_equal(getattr(mapped, q), getattr(reader, q),
                                          err_msg=f"{name}: {q}")
    # the map the tools give each folder (tools/fsae_identify.py's sidecars) is this one
    from damper_emulator.dyno.fsae import column_map

    assert all(column_map(DATA / name) == cmap for name in top)
    flipped = [k for k in runs if k.startswith("pressure_testing/")]
    assert flipped and all(column_map(DATA / name) == dataclasses.replace(cmap, force_sign=-1.0)
                           for name in flipped)
    for name in flipped[:1]:
        with pytest.raises(MeasuredDataError, match="--force-sign -1"):
            read_mapped_csv(DATA / name, cmap)
        np.testing.assert_array_equal(
            read_mapped_csv(DATA / name, dataclasses.replace(cmap, force_sign=-1.0)).force,
            runs[name].force)
