"""Virtual dyno command line and measured-data files (docs/interfaces.md §2,
"Command line").

End-to-end checks run ``python -m damper_hil.cli`` in a subprocess (exit status,
exactly what reaches stderr); the others call ``main()`` in-process to stay fast.
"""

import gzip
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from damper_emulator.dyno.measured import MeasuredDataError, read_measured_csv, write_measured_csv
from damper_emulator.params import DEFAULT_PARAMS_FILE
from damper_hil.cli import main


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "damper_hil.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300, cwd=cwd)


def zero_crossings(t, x):
    """Times where ``x`` changes sign (either way), linearly interpolated."""
    i = np.flatnonzero(((x[:-1] < 0) & (x[1:] >= 0)) | ((x[:-1] > 0) & (x[1:] <= 0)))
    return t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])


def is_png(path: Path) -> bool:
    return path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------------------
# dyno: end to end


@pytest.mark.slow
def test_sine_writes_readable_file_with_requested_motion(tmp_path):
    out = tmp_path / "dyno"
    res = run_cli("dyno", "--protocol", "sine", "--frequency", 3, "--amplitude", 0.05,
                  "--cycles", 3, "--out", out)
    assert res.returncode == 0, res.stderr
    assert f"wrote {out / 'sine_3hz.csv'}" in res.stderr.splitlines()
    data = read_measured_csv(out / "sine_3hz.csv")
    assert data.name == "sine_3hz.csv"
    assert data.velocity is not None and data.temperature is None
    # settle cycle dropped: the file starts at t = 0, x = 0 and covers 3 periods at 1 kHz
    assert data.time[0] == 0.0 and data.displacement[0] == pytest.approx(0.0, abs=1e-12)
    assert np.allclose(np.diff(data.time), 1e-3)
    assert data.duration_s == pytest.approx(1.0, abs=1e-9)
    assert np.abs(data.displacement).max() == pytest.approx(0.05, abs=1e-6)
    half_periods = np.diff(zero_crossings(data.time, data.displacement))
    assert half_periods.size >= 4 and np.allclose(2 * half_periods, 1 / 3, rtol=1e-6)
    assert is_png(out / "sine_3hz.png")

    doc = json.loads((out / "dyno.json").read_text())
    assert doc["protocol"] == "sine"
    assert doc["options"]["frequency"] == 3 and doc["options"]["rate"] == 1000
    assert set(doc["files"]) == {"sine_3hz.csv", "sine_3hz.png", "dyno.json"}
    energy = doc["summary"]["energy_per_cycle_j"]
    assert energy > 0
    # the same energy from the file: ∮ F dx over the 3 recorded cycles
    x, f = data.displacement, data.force
    assert np.sum(0.5 * (f[1:] + f[:-1]) * np.diff(x)) / 3 == pytest.approx(energy, rel=1e-6)
    assert doc["summary"]["faults"] == []


def test_invalid_params_file_is_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.yaml"
    text, n = re.subn(r"rod_diameter_m:\s*\S+", "rod_diameter_m: 40.0e-3",
                      DEFAULT_PARAMS_FILE.read_text())
    assert n == 1
    bad.write_text(text)  # rod thicker than the 36 mm piston
    res = run_cli("dyno", "--protocol", "sine", "--params", bad, "--out", tmp_path / "o")
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("damper-hil: error: ")
    assert "rod_diameter_m" in lines[0] and str(bad) in lines[0]
    assert not (tmp_path / "o" / "sine_1hz.csv").exists()


@pytest.mark.parametrize(("args", "needle"), [
    (["--protocol", "chirp", "--frequency", "3"], "--frequency does not apply"),
    (["--protocol", "sine", "--amplitude", "0.5"], "travel"),
    (["--protocol", "sine", "--frequency", "400"], "sample rate"),
])
def test_bad_option_values_are_one_line_exit_2(tmp_path, capsys, args, needle):
    assert main(["dyno", *args, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("damper-hil: error: ") and needle in err[0]


def test_usage_error_exits_2(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["dyno", "--protocol", "sine", "--frequency", "-1", "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert "--frequency" in capsys.readouterr().err


def test_unwritable_output_is_one_line_exit_2(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    assert main(["dyno", "--protocol", "sine", "--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("damper-hil: error: ")
    assert "Traceback" not in "".join(err)


def test_fourteen_speed_peaks_are_monotonic(tmp_path, capsys):
    assert main(["dyno", "--protocol", "14-speed", "--out", str(tmp_path)]) == 0
    table = json.loads((tmp_path / "dyno.json").read_text())["summary"]["table"]
    vr, fr = np.array(table["peak_velocity_rebound_m_s"]), np.array(table["peak_force_rebound_n"])
    vc = np.array(table["peak_velocity_compression_m_s"])
    fc = np.array(table["peak_force_compression_n"])
    assert vr.size == 14
    assert vr[0] == pytest.approx(0.025, rel=1e-3) and vr[-1] == pytest.approx(1.5, rel=1e-3)
    assert np.all(np.diff(vr) > 0) and np.all(np.diff(fr) > 0)
    assert np.all(np.diff(vc) < 0) and np.all(np.diff(fc) < 0)
    assert np.all(fr > fc)
    lines = (tmp_path / "14speed.csv").read_text().splitlines()
    assert lines[0] == ("frequency_hz,peak_velocity_rebound_m_s,peak_force_rebound_n,"
                        "peak_velocity_compression_m_s,peak_force_compression_n")
    assert len(lines) == 15
    assert is_png(tmp_path / "14speed.png")


def test_quasi_static_default_lasts_150_s_at_50_hz(tmp_path, capsys):
    assert main(["dyno", "--protocol", "quasi-static", "--out", str(tmp_path)]) == 0
    data = read_measured_csv(tmp_path / "quasi_static.csv")
    assert len(data) == 7501
    assert data.duration_s == pytest.approx(150.0, abs=1e-9)
    assert np.allclose(np.diff(data.time), 0.02)
    assert np.allclose(np.abs(data.velocity), 0.004)
    # the 50 Hz grid need not hit the turning points: within one sample of travel
    assert np.abs(data.displacement).max() == pytest.approx(0.075, abs=0.004 / 50)
    summary = json.loads((tmp_path / "dyno.json").read_text())["summary"]
    assert 40 < summary["friction_estimate_n"] < 80  # 43.7 N Coulomb + a little viscous
    assert is_png(tmp_path / "quasi_static.png")


def test_chirp_with_noise_is_reproducible(tmp_path, capsys):
    """The same seed gives the same file; ``--no-plot`` changes nothing but the PNG."""
    args = ["dyno", "--protocol", "chirp", "--duration", "2", "--noise-std", "5",
            "--seed", "7"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--no-plot", "--out", str(tmp_path / "b")]) == 0
    a = read_measured_csv(tmp_path / "a" / "chirp.csv")
    b = read_measured_csv(tmp_path / "b" / "chirp.csv")
    assert len(a) == 2001 and np.array_equal(a.force, b.force)
    assert is_png(tmp_path / "a" / "chirp.png")
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["chirp.csv", "dyno.json"]
    files = json.loads((tmp_path / "b" / "dyno.json").read_text())["files"]
    assert files == ["chirp.csv", "dyno.json"]
    err = capsys.readouterr().err
    assert f"wrote {tmp_path / 'a' / 'chirp.csv'}" in err


@pytest.mark.slow
def test_demo_writes_everything(tmp_path, capsys):
    assert main(["dyno-demo", "--duration", "2", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "[1/7]" in err and "[7/7]" in err
    doc = json.loads((tmp_path / "demo.json").read_text())
    for name in ("quasi_static.csv", "chirp.csv", "sine_1hz.csv", "sine_3hz.csv",
                 "sine_12hz.csv", "14speed.csv", "paper_sines.png", "demo.json"):
        assert name in doc["files"] and (tmp_path / name).is_file()
    assert all(is_png(tmp_path / n) for n in doc["files"] if n.endswith(".png"))
    e1, e3 = (doc["results"][k]["energy_per_cycle_j"] for k in ("sine_1hz", "sine_3hz"))
    assert 0 < e1 < e3  # same stroke, three times the speed
    assert len(read_measured_csv(tmp_path / "sine_12hz.csv")) == 251


# --------------------------------------------------------------------------------------
# measured-data files


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# forces a damper could give at 1 m/s (the unit checks refuse a toy 10 N at 1 m/s as kN)
GOOD = "time,displacement,force\n0,0,1000\n0.001,0.001,2000\n0.002,0.002,3000\n"


@pytest.mark.parametrize(("text", "row", "needle"), [
    ("time,displacement\n0,0\n0.001,0.001\n", None, "missing required column 'force'"),
    ("time,displacement,force\n0,0,10\n0.001,nan,20\n0.002,0.002,30\n", 2, "displacement"),
    ("time,displacement,force\n0,0,10\n0.001,0.001,inf\n0.002,0.002,30\n", 2, "force"),
    ("time,displacement,force\n0,0,10\n0.001,0.001,abc\n", 2, "not a number"),
    ("time,displacement,force\n0,0,10\n0.002,0.001,20\n0.001,0.002,30\n", 3,
     "not strictly increasing"),
    ("time,displacement,force\n0,0,10\n0.001,0.001,20\n0.001,0.002,30\n", 3,
     "not strictly increasing"),
    # the first row beyond the bound
    ("time,displacement,force\n0,0,10\n0.001,12.5,20\n0.002,25.0,30\n", 2,
     "looks like millimetres; expected metres"),
    ("time,displacement,velocity,force\n0,0,0,10\n0.001,0.001,800,20\n", 2, "mm/s"),
    # force in kN: 0.4 at most while the rod strokes 2 mm (a damper gives tens of N)
    ("time,displacement,force\n0,0,0.1\n0.001,0.001,-0.4\n0.002,0.002,0.3\n", 2,
     "looks like kilonewtons; expected newtons"),
    # time in ms: 1 ms steps written as 1
    ("time,displacement,force\n0,0,1000\n1,0.001,2000\n2,0.002,3000\n", 2,
     "looks like milliseconds; expected seconds"),
    # time in ms over more than a day in ms (86.4 s): the row that passes the day
    ("time,displacement,force\n0,0,1000\n0.1,0.001,2000\n0.2,0.002,3000\n"
     "90000,0.003,2000\n", 4, "more than a day"),
    ("time,displacement,force\n0,0,10\n0.001,0.001\n", 2, "no value for column 'force'"),
    ("time,displacement,force\n0,0,10\n", None, "need at least 2"),
    ("time,displacement,force\n", None, "need at least 2"),
    ("", None, "empty file"),
])
def test_reader_rejects_malformed_file_naming_file_and_row(tmp_path, text, row, needle):
    path = _write(tmp_path / "bad.csv", text)
    with pytest.raises(MeasuredDataError) as exc:
        read_measured_csv(path)
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(str(path))
    assert needle in msg
    if row is not None:
        assert f"row {row} " in msg


def test_reader_row_numbers_skip_blank_lines(tmp_path):
    path = _write(tmp_path / "blank.csv", "time,displacement,force\n0,0,1\n\n0.1,x,2\n")
    with pytest.raises(MeasuredDataError, match=r"row 2 \(line 4\)"):
        read_measured_csv(path)


def test_reader_row_numbers_skip_blank_lines_after_a_fast_read(tmp_path):
    # every field numeric, so numpy reads the file; the unit check then names the row of
    # the peak force (the 3rd data row) and its line in the file, counted by hand
    path = _write(tmp_path / "blank_kn.csv",
                  "time,displacement,force\n0,0,1\n\n0.001,0.001,2\n\n0.002,0.002,3\n")
    with pytest.raises(MeasuredDataError, match=r"row 3 \(line 6\): force peaks at 3 "):
        read_measured_csv(path)


def test_fast_and_field_by_field_reads_agree(tmp_path):
    """numpy's read (all columns numeric) and the field-by-field one (forced by a parser)
    give the same floats, blank lines, CRLF and extra columns included."""
    from damper_emulator.dyno.measured import (
        OPTIONAL_COLUMNS,
        REQUIRED_COLUMNS,
        parse_number,
        read_csv_table,
    )
    rng = np.random.default_rng(5)
    values = rng.normal(0.0, 1.0, (200, 3)) * [1.0, 1e-2, 1e3]
    body = "".join(f"{float(a)!r},{b:.17g},note,{c:.6e}\r\n" + ("\r\n" if k % 50 == 0 else "")
                   for k, (a, b, c) in enumerate(values))
    path = _write(tmp_path / "mixed.csv", "time,displacement,comment,force\r\n" + body)
    fast = read_csv_table(path, REQUIRED_COLUMNS, OPTIONAL_COLUMNS)
    slow = read_csv_table(path, REQUIRED_COLUMNS, OPTIONAL_COLUMNS,
                          parsers={"time": parse_number})
    assert isinstance(fast.values["time"], np.ndarray) and isinstance(slow.values["time"], list)
    assert fast.rows == slow.rows == 200
    for k, col in enumerate(REQUIRED_COLUMNS):
        np.testing.assert_array_equal(fast.values[col], np.asarray(slow.values[col]))
        np.testing.assert_array_equal(fast.values[col],
                                      [float(f"{v:.6e}") if col == "force" else v
                                       for v in values[:, k]])


def test_reader_missing_file_is_measured_data_error(tmp_path):
    with pytest.raises(MeasuredDataError, match=r"nope\.csv"):
        read_measured_csv(tmp_path / "nope.csv")


def test_round_trip_gzip_extra_columns_and_optional_columns(tmp_path):
    t = np.arange(5) * 1e-3
    x = 0.01 * np.sin(t * 100)
    v = 1.0 * np.cos(t * 100)
    f = 1234.5678901 * v
    temp = np.full(5, 42.5)
    path = write_measured_csv(tmp_path / "rt.csv.gz", t, x, f, velocity=v, temperature=temp)
    with gzip.open(path, "rt") as fh:
        assert fh.readline().strip() == "time,displacement,velocity,force,temperature"
    data = read_measured_csv(path)
    assert data.name == "rt.csv.gz"
    np.testing.assert_allclose(data.force, f, rtol=1e-8)
    np.testing.assert_allclose(data.velocity, v, rtol=1e-8)
    np.testing.assert_allclose(data.temperature, temp)
    # extra columns ignored, column order free, names case/blank-insensitive
    extra = _write(tmp_path / "extra.csv",
                   "Force , comment,TIME,displacement\n100,a,0,0\n200,b,0.1,0.01\n")
    data = read_measured_csv(extra)
    np.testing.assert_array_equal(data.force, [100, 200])
    assert data.velocity is None and data.temperature is None
    np.testing.assert_array_equal(read_measured_csv(
        _write(tmp_path / "good.csv", GOOD)).force, [1000, 2000, 3000])


def _sine_file(path: Path, n: int = 2000, rate: float = 1000.0, edit=None) -> Path:
    """A plausible 2 Hz sine test (40 mm, about 2 kN), optionally edited row by row
    (``edit(t, x, v, f, T)`` changes the arrays in place)."""
    t = np.arange(n) / rate
    x = 0.02 * np.sin(2 * np.pi * 2.0 * t)
    v = 0.02 * 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t)
    f = 8000.0 * v + 400.0
    temp = np.full(n, 40.0)
    if edit is not None:
        edit(t, x, v, f, temp)
    write_measured_csv(path, t, x, f, velocity=v, temperature=temp)
    return path


def _set(column: str, row: int, value: float):
    names = ("t", "x", "v", "f", "T")

    def edit(*arrays):
        arrays[names.index(column)][row - 1] = value
    return edit


@pytest.mark.parametrize(("edit", "row", "needle"), [
    # a whole file 10^12 times too large, and one absurd sample in a good file
    (lambda t, x, v, f, T: f.__imul__(1e12), 1, "exceeds 100000 N in magnitude"),
    (_set("f", 700, 1e9), 700, "exceeds 100000 N in magnitude"),
    # one sample within the bound but alone far beyond all others: a spike
    (_set("f", 700, 60e3), 700, "lone spike"),
    (_set("T", 900, 160.0), 900, "lone spike"),
    (_set("T", 900, -80.0), 900, "below the -60 °C"),
    # one displacement sample jumped (within the 1 m bound): faster than any dyno
    (_set("x", 1200, 0.5), 1200, "displacement jumps"),
    (_set("v", 50, 35.0), 50, "exceeds 20 m/s"),
    # a time stamp 0.1 ns after the one before, and a 5-minute gap
    (lambda t, x, v, f, T: t.__setitem__(slice(301, None), t[301:] - 0.999999e-3), 302,
     "less than the 1e-06 s"),
    (lambda t, x, v, f, T: t.__setitem__(slice(1000, None), t[1000:] + 300.0), 1001,
     "time jumps by 300.001 s"),
])
def test_samples_no_dyno_can_produce_are_refused_naming_the_row(tmp_path, edit, row, needle):
    """Force, displacement, velocity, temperature and time are each bounded above and
    below by what a damper dyno can produce (damper_emulator.dyno.limits); a single absurd
    sample is refused naming its row."""
    path = _sine_file(tmp_path / "sine.csv", edit=edit)
    with pytest.raises(MeasuredDataError) as exc:
        read_measured_csv(path)
    msg = str(exc.value)
    assert needle in msg and f"row {row} " in msg and "\n" not in msg, msg


def test_the_plausible_file_of_those_tests_is_accepted(tmp_path):
    data = read_measured_csv(_sine_file(tmp_path / "sine.csv"))
    assert len(data) == 2000 and np.ptp(data.force) > 1000


def test_validate_and_identify_refuse_an_absurd_file_with_one_line(tmp_path, cli):
    """Forces 10^12 times too large (r.m.s. 3.9e14 N) are refused by validate, not scored
    with exit 0, and identify names the spike rather than the sign convention."""
    big = _sine_file(tmp_path / "big.csv", edit=lambda t, x, v, f, T: f.__imul__(1e12))
    res = cli("validate", "--params", "config/sport.yaml", big)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert "exceeds 100000 N" in res.stderr
    spike = _sine_file(tmp_path / "chirp.csv", edit=_set("f", 700, 60e3))
    qs = _sine_file(tmp_path / "qs.csv", n=500, rate=50.0)
    res = cli("identify", "--quasi-static", qs, "--chirp", spike, "--out",
              tmp_path / "p.yaml")
    assert res.returncode == 2 and "row 700 " in res.stderr and "lone spike" in res.stderr
    assert "sign convention" not in res.stderr and res.stderr.count("\n") == 1


def test_a_dyno_recording_no_dyno_produces_is_kept_and_refused(tmp_path, sport_model):
    """The dyno's recordings (the model's, or a dyno's over CAN: whatever engine gives the
    forces) pass the same checks: a load cell that reads one absurd sample gives one line
    naming the file and the row, and the recording is kept to look at."""
    from damper_emulator.dyno.runner import run_sine
    from damper_emulator.model.compressible import simulate

    def faulty_load_cell(model, t, x, v):
        res = simulate(model, t, x, v)
        res.force_n[-100] = 5e5     # in the recorded part (after the lead-in)
        return res

    with pytest.raises(MeasuredDataError, match=r"sine_2hz.csv: row (\d+): force 500000"
                       ) as exc:
        run_sine(sport_model, tmp_path, 2.0, 0.02, engine=faulty_load_cell)
    kept = np.loadtxt(tmp_path / "sine_2hz.csv", delimiter=",", skiprows=1)
    row = int(re.search(r"row (\d+)", str(exc.value))[1])
    assert row == kept.shape[0] - 99 and kept[row - 1, -1] == 5e5
