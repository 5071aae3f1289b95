"""Lab exports through a column map (damper_emulator/dyno/column_map.py): renamed columns,
units converted by pint, ISO time stamps, signs and zero, the energy check; the same
identification as from the project's own CSV.  The exports are written here with the
csv module (not the project's writer), in units the project does not use."""

from __future__ import annotations

import csv
import gzip
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
from measured_support import assert_same_identification, protocol_records
from scipy.integrate import trapezoid

from damper_emulator.dyno.column_map import (
    SIDECAR,
    ColumnMap,
    ColumnMapError,
    dissipated_fraction,
    load_column_map,
    parse_assignments,
    read_mapped_csv,
    sidecar_map,
    unit_in_name,
    write_sidecar,
)
from damper_emulator.dyno.measured import MeasuredDataError, read_measured_csv, write_measured_csv
from damper_emulator.dyno.measured_bag import read_measured
from damper_emulator.errors import UserError

MM, INCH, LBF = 1e-3, 0.0254, 4.4482216152605
START = datetime(2025, 11, 14, 20, 7, 10, 531160)
#: the lab's export of the SI file's columns: its header and how it writes each value
LAB = {"time": ("Timestamp", lambda t: (START + timedelta(seconds=float(t))).isoformat(" ")),
       "displacement": ("Position [in]", lambda x: repr(-x / INCH)),   # compression +
       "force": ("Force_lbf", lambda f: repr(f / LBF)),
       "temperature": ("Oil temp (degF)", lambda c: repr(c * 9 / 5 + 32))}
LAB_MAP = ColumnMap(columns={q: name for q, (name, _) in LAB.items()},
                    displacement_sign=-1.0)


def lab_export(si: Path, out: Path, gz: bool = False) -> Path:
    """The SI file ``si`` as a lab writes it (:data:`LAB`), with a column the map does not
    name in front and the columns in another order."""
    with open(si, newline="") as fh:
        rows = list(csv.DictReader(fh))
    opener = gzip.open if gz else open
    with opener(out, "wt", newline="") as fh:
        w = csv.writer(fh)
        order = ["force", "time", "temperature", "displacement"]
        w.writerow(["Force (V)", *[LAB[q][0] for q in order]])
        for r in rows:
            w.writerow(["0.31", *[LAB[q][1](float(r[q])) for q in order]])
    return out


def _sine(n: int = 2001, rate: float = 1000.0) -> tuple[np.ndarray, ...]:
    """A damper-like record: a 2 Hz sine, viscous and Coulomb force about a gas force."""
    t = np.arange(n) / rate
    x = 0.02 * np.sin(2 * np.pi * 2 * t)
    v = 0.02 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t)
    f = 3000.0 * v + 40.0 * np.tanh(v / 0.01) - 300.0
    return t, x, f, v, 25.0 + 10.0 * t


@pytest.fixture
def si_file(tmp_path) -> Path:
    t, x, f, _v, temp = _sine()
    path = tmp_path / "si.csv"
    write_measured_csv(path, t, x, f, temperature=temp)
    return path


@pytest.mark.parametrize("gz", [False, True])
def test_a_lab_export_reads_as_the_si_file(si_file, tmp_path, gz):
    plain = read_measured_csv(si_file)
    lab = read_mapped_csv(lab_export(si_file, tmp_path / ("lab.csv" + ".gz" * gz), gz),
                          LAB_MAP)
    # ISO stamps carry microseconds: the 1 ms samples are exact; units to rounding
    np.testing.assert_allclose(lab.time, plain.time, rtol=0, atol=1e-9)
    for q in ("displacement", "force", "temperature"):
        np.testing.assert_allclose(getattr(lab, q), getattr(plain, q), rtol=1e-12,
                                   atol=1e-12, err_msg=q)


def test_units_from_the_names():
    assert [unit_in_name(n) for n in ("Force (N)", "Position [in]", "force_kN", "Temp_degF",
                                      "Displacement (mm)", "time", "Timestamp")] == \
        ["N", "in", "kN", "degF", "mm", None, None]


def test_an_identification_from_the_export_is_the_one_from_the_si_files(
        tmp_path, sport_cfg, sport_model):
    """The done-when of the column map: the same identification (to IDENTIFICATION_RTOL:
    measured_support.py says why not 1e-9)."""
    si, lab = [], []
    for name, t, x, f, temp in protocol_records(sport_model, 3):
        path = write_measured_csv(tmp_path / f"{name}.csv", t, x, f, temperature=temp)
        si.append(read_measured_csv(path))
        lab.append(read_mapped_csv(lab_export(path, tmp_path / f"{name}_lab.csv"), LAB_MAP))
    assert_same_identification(si, lab, sport_cfg)


@pytest.mark.parametrize(("columns", "words"), [
    ({"force": "Force (blorts)"}, "unknown unit 'blorts'"),
    ({"force": "Force (1/0)"}, "cannot read the unit '1/0'"),
    ({"force": "Force [(N]"}, r"cannot read the unit '\(N'"),
    ({"force": "Force (1e5 N)"}, "cannot read the unit"),
    ({"force": "Force (mm)"}, "'mm' is not a unit of force"),
    ({"displacement": "x [lbf]"}, "'lbf' is not a unit of displacement"),
])
def test_an_unknown_or_wrong_unit_is_one_line(tmp_path, columns, words):
    t, x, f, _v, _ = _sine(200)
    path = tmp_path / "f.csv"
    names = {"time": "time", "displacement": "displacement", "force": "force", **columns}
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([names["time"], names["displacement"], names["force"]])
        w.writerows(zip(t, x, f))
    with pytest.raises(ColumnMapError, match=words) as err:
        read_mapped_csv(path, ColumnMap(columns=columns))
    assert isinstance(err.value, UserError) and "\n" not in str(err.value)


def test_a_flipped_force_is_refused_and_the_flag_puts_it_right(si_file, tmp_path):
    plain = read_measured_csv(si_file)
    flipped = tmp_path / "flipped.csv"
    write_measured_csv(flipped, plain.time, plain.displacement, -plain.force)
    with pytest.raises(MeasuredDataError, match="--force-sign -1") as err:
        read_mapped_csv(flipped, ColumnMap())
    assert "\n" not in str(err.value)
    fixed = read_mapped_csv(flipped, ColumnMap(force_sign=-1.0))
    np.testing.assert_array_equal(fixed.force, plain.force)
    # the energy measure itself: +1 for a force that only resists, -1 flipped
    v = plain.velocity_or_derivative()
    resisting = 500.0 * v
    x = plain.displacement
    assert dissipated_fraction(plain.time, v, resisting, x) == pytest.approx(1.0, abs=1e-3)
    assert dissipated_fraction(plain.time, v, -resisting, x) == pytest.approx(-1.0, abs=1e-3)


def test_a_slow_test_that_ends_elsewhere_is_not_refused_for_its_gas_force(tmp_path):
    """A quasi-static triangle 0 → +A → 0 → −A → 0 → +A, cut at +A: the gas force
    (−400 N and a spring) does −400 N·A of net work, more than the friction's 44 N over
    the 5 A travelled; taken out, the friction alone remains, which dissipates."""
    speed, amplitude = 0.004, 0.05
    legs = np.concatenate([np.linspace(0, amplitude, 101), np.linspace(amplitude, -amplitude,
                           201)[1:], np.linspace(-amplitude, amplitude, 201)[1:]])
    t = np.arange(legs.size) * (amplitude / 100) / speed       # 0.5 mm steps at 4 mm/s
    v = np.gradient(legs, t)
    force = -400.0 - 3000.0 * legs + 44.0 * np.sign(v)
    good, flipped = tmp_path / "qs.csv", tmp_path / "qs_flipped.csv"
    write_measured_csv(good, t, legs, force)
    write_measured_csv(flipped, t, legs, -force)
    raw = force * v
    assert trapezoid(raw, t) < -0.1 * trapezoid(np.abs(raw), t)  # the case at issue
    read_mapped_csv(good, ColumnMap())
    with pytest.raises(MeasuredDataError, match="--force-sign -1"):
        read_mapped_csv(flipped, ColumnMap())


def test_sample_rate_and_mid_stroke_zero(tmp_path):
    t, x, f, _v, _ = _sine()
    path = tmp_path / "no_time.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["Stroke (mm)", "Load (kN)"])
        w.writerows(zip((x + 0.05) / MM, f / 1000.0))
    data = read_mapped_csv(path, ColumnMap(
        columns={"displacement": "Stroke (mm)", "force": "Load (kN)"}, sample_rate_hz=1000.0,
        displacement_zero="mid-stroke"))
    np.testing.assert_allclose(data.time, t, rtol=0, atol=1e-15)
    mid = 0.5 * (x.min() + x.max())
    np.testing.assert_allclose(data.displacement, x - mid, rtol=0, atol=1e-15)
    np.testing.assert_allclose(data.force, f, rtol=1e-12)


def test_a_sidecar_beside_the_files_is_their_map(si_file, tmp_path):
    folder = tmp_path / "exports"
    folder.mkdir()
    lab = lab_export(si_file, folder / "run1.csv")
    (folder / "columns.yaml").write_text(
        "columns:\n" + "".join(f"  {q}: '{name}'\n" for q, (name, _) in LAB.items())
        + "displacement_sign: -1\n")
    via_sidecar = read_measured(lab)
    np.testing.assert_array_equal(via_sidecar.force, read_mapped_csv(lab, LAB_MAP).force)
    (folder / "columns.yaml").write_text("columns: {force: F}\nforce_sing: -1\n")
    with pytest.raises(ColumnMapError, match="unknown key 'force_sing'"):
        read_measured(lab)


def test_bad_maps_are_one_line():
    for make, words in ((lambda: ColumnMap(columns={"forces": "F"}), "unknown quantity"),
                        (lambda: ColumnMap(force_sign=2.0), "force_sign must be 1 or -1"),
                        (lambda: ColumnMap(columns={"time": "t"}, sample_rate_hz=100.0),
                         "give one"),
                        (lambda: parse_assignments(["force"]), "not QUANTITY=COLUMN"),
                        (lambda: parse_assignments(["force=a", "FORCE=b"]), "given twice")):
        with pytest.raises(ColumnMapError, match=words):
            make()


def test_the_command_line_takes_a_map(si_file, tmp_path, capsys):
    from damper_hil.cli import main

    lab = lab_export(si_file, tmp_path / "lab.csv")
    params = str(Path(__file__).resolve().parents[1] / "config" / "sport.yaml")
    columns = [f"{q}={name}" for q, (name, _) in LAB.items()]
    args = ["validate", "--params", params, str(lab), "--json", str(tmp_path / "v.json"),
            "--displacement-sign", "-1", "--columns", *columns]
    assert main(args) == 0
    # the same export with its force in an unknown unit: one line, exit 2
    bad = tmp_path / "bad.csv"
    bad.write_text(lab.read_text().replace("Force_lbf", "Force (blorts)", 1))
    capsys.readouterr()
    bad_columns = [c if not c.startswith("force=") else "force=Force (blorts)"
                   for c in columns]
    assert main([*args[:3], str(bad), *args[4:-len(columns)], *bad_columns]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown unit 'blorts'" in err and "\n" not in err


def test_fleet_reads_a_damper_folder_of_exports_through_its_sidecar(si_file, tmp_path):
    from damper_hil.fleet.inputs import find_dampers
    from damper_hil.fleet.runner import load_job

    folder = tmp_path / "batch" / "unit_01"
    folder.mkdir(parents=True)
    for name in ("quasi_static.csv", "chirp.csv", "sine_1hz.csv"):
        lab_export(si_file, folder / name)
    (folder / "columns.yaml").write_text(
        "columns:\n" + "".join(f"  {q}: '{name}'\n" for q, (name, _) in LAB.items())
        + "displacement_sign: -1\n")
    (damper,) = find_dampers(tmp_path / "batch")
    job = load_job(damper, False, None)
    expected = read_measured_csv(si_file)
    for data in (*job.quasi_static, *job.chirp, *job.validate):
        np.testing.assert_allclose(data.force, expected.force, rtol=1e-12)
        np.testing.assert_allclose(data.displacement, expected.displacement, rtol=1e-12,
                                   atol=1e-15)


def test_names_that_end_in_a_word_and_stamps_as_labs_write_them(tmp_path):
    """A _word that is not a unit of the quantity is part of the name; upper-case units
    are read; ISO stamps with a Z, a decimal comma or seven digits, and a zone in the
    time column's name, read as seconds since the first."""
    from damper_emulator.dyno.column_map import column_units

    for quantity, name, expected in (("displacement", "piston_position", None),
                                     ("force", "load_cell", None),
                                     ("displacement", "disp_ch2", None),
                                     ("time", "time_a", None),
                                     ("force", "FORCE_KN", (1000.0, 0.0)),
                                     ("displacement", "DISP_MM", (0.001, 0.0))):
        assert column_units(quantity, name) == expected, name
    t, x, f, _v, _ = _sine(200)
    path = tmp_path / "stamps.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["Timestamp (UTC)", "piston_position", "load_cell"])
        for k, (xi, fi) in enumerate(zip(x, f)):
            stamp = (START + timedelta(milliseconds=k)).isoformat("T")
            stamp = stamp.replace(".", ",") + "1Z" if k % 2 else stamp + "Z"
            w.writerow([stamp, xi, fi])
    data = read_mapped_csv(path, ColumnMap(columns={"time": "Timestamp (UTC)",
                                                    "displacement": "piston_position",
                                                    "force": "load_cell"}))
    np.testing.assert_allclose(data.time, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(data.force, f)


def test_one_stroke_is_not_judged_and_command_line_settings_join_the_sidecar(tmp_path):
    """Within one stroke the friction is the line's offset and the rest tells little: a
    file that moves one way only is read as it is, even with its force's sign wrong (the
    measure would refuse it: checked).  A --force-sign on the command line is laid over
    the folder's sidecar, whose column names stay."""
    from damper_emulator.dyno.column_map import ColumnOptions

    w = 2 * np.pi * 0.5
    t = np.linspace(-0.5, 0.5, 501)
    x, v = 0.03 * np.sin(w * t), 0.03 * w * np.cos(w * t)       # compression → extension
    force = -400.0 / (1 + x / 0.08) ** 1.4 + 44.0 + 1000.0 * v  # gas, friction, valves
    assert dissipated_fraction(t, v, -force, x) < -0.1
    folder = tmp_path / "exports"
    folder.mkdir()
    path = folder / "stroke.csv"
    with open(path, "w", newline="") as fh:
        w_ = csv.writer(fh)
        w_.writerow(["t (s)", "x (mm)", "v (mm/s)", "F (N)"])
        w_.writerows(zip(t + 0.5, x / MM, v / MM, -force))        # compression-positive
    (folder / "columns.yaml").write_text("columns: {time: t (s), displacement: x (mm), "
                                         "velocity: v (mm/s), force: F (N)}\n")
    assert np.array_equal(read_measured(path).force, -force)     # one way: not judged
    options = ColumnOptions(settings={"force_sign": -1.0})
    data = read_measured(path, options.for_file(path))
    np.testing.assert_allclose(data.force, force, rtol=1e-12)
    np.testing.assert_allclose(data.displacement, x, rtol=1e-12, atol=1e-15)


def test_a_map_written_as_a_sidecar_reads_back_as_it_was(tmp_path):
    """write_sidecar is load_column_map's inverse: a folder of exports carries its map,
    and every file in it is read through it."""
    cmap = ColumnMap(columns=LAB_MAP.columns, force_sign=-1.0, displacement_zero="mid-stroke",
                     velocity_window=7)
    path = write_sidecar(tmp_path, cmap)
    assert path == tmp_path / SIDECAR
    assert load_column_map(path) == cmap
    assert sidecar_map(tmp_path / "any.csv") == cmap
    assert "sample_rate_hz" not in path.read_text()          # defaults left out
    rate = ColumnMap(columns={"force": "F [kN]"}, sample_rate_hz=300.0)
    assert load_column_map(write_sidecar(tmp_path / "rate", rate)) == rate
