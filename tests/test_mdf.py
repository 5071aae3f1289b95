"""ASAM MDF files as measured data (damper_emulator/dyno/mdf.py): written here by asammdf's
own writer, with renamed channels in other units, a temperature on a slower raster, read
through a column map to the record, and the same identification."""

from __future__ import annotations

import numpy as np
import pytest

asammdf = pytest.importorskip("asammdf")
from asammdf import MDF, Signal  # noqa: E402
from measured_support import assert_same_identification, protocol_records  # noqa: E402

from damper_emulator.dyno.column_map import ColumnMap, ColumnMapError  # noqa: E402
from damper_emulator.dyno.mdf import read_mapped_mdf  # noqa: E402
from damper_emulator.dyno.measured import MeasuredData, MeasuredDataError  # noqa: E402
from damper_emulator.dyno.measured_bag import read_measured  # noqa: E402

INCH, LBF = 0.0254, 4.4482216152605
MAP = ColumnMap(columns={"displacement": "DamperTravel", "force": "LoadCell",
                         "temperature": "OilTemp"}, displacement_sign=-1.0)


def write_mf4(path, t, x, f, temperature):
    """The record as a measurement tool writes it: the stroke (compression +, inches) and
    the load (lbf) in one channel group at the record's rate, the oil temperature (degF)
    in another at a tenth of it."""
    mdf = MDF(version="4.10")
    mdf.append([Signal(-x / INCH, t, name="DamperTravel", unit="in"),
                Signal(f / LBF, t, name="LoadCell", unit="lbf")], comment="dyno")
    mdf.append([Signal(temperature[::10] * 9 / 5 + 32, t[::10], name="OilTemp",
                       unit="degF")], comment="slow")
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def _record(n=2001):
    t = np.arange(n) / 1000.0
    x = 0.02 * np.sin(2 * np.pi * 2 * t)
    v = 0.02 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t)
    return t, x, 3000.0 * v + 40.0 * np.tanh(v / 0.01) - 300.0, 25.0 + 10.0 * t


def test_an_mf4_file_reads_as_its_record(tmp_path):
    t, x, f, temp = _record()
    data = read_mapped_mdf(write_mf4(tmp_path / "run.mf4", t, x, f, temp), MAP)
    np.testing.assert_allclose(data.time, t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(data.displacement, x, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(data.force, f, rtol=1e-12)
    # the slow raster interpolated onto the force's: the linear temperature exactly
    np.testing.assert_allclose(data.temperature[:-10], temp[:-10], rtol=1e-12)


def test_an_identification_from_an_mf4_file_is_the_one_from_its_record(
        tmp_path, sport_cfg, sport_model):
    si, mdf = [], []
    for name, t, x, f, temp in protocol_records(sport_model, 5):
        si.append(MeasuredData(t, x, f, temperature=temp))
        mdf.append(read_mapped_mdf(write_mf4(tmp_path / f"{name}.mf4", t, x, f, temp), MAP))
    assert_same_identification(si, mdf, sport_cfg)


def test_bad_mdf_files_are_one_line(tmp_path):
    t, x, f, temp = _record(200)
    path = write_mf4(tmp_path / "run.mf4", t, x, f, temp)
    for cmap, kind, words in (
            (ColumnMap(columns={"displacement": "Stroke", "force": "LoadCell"}),
             MeasuredDataError, r"no channel 'Stroke' \(have: DamperTravel, LoadCell"),
            (ColumnMap(columns={"displacement": "OilTemp", "force": "LoadCell"}),
             ColumnMapError, "'degF' is not a unit of displacement")):
        with pytest.raises(kind, match=words) as err:
            read_mapped_mdf(path, cmap)
        assert "\n" not in str(err.value)
    junk = tmp_path / "junk.mf4"
    junk.write_bytes(b"not an mdf file " * 8)
    with pytest.raises(MeasuredDataError, match="not an MDF file asammdf can read") as err:
        read_measured(junk, MAP)
    assert "\n" not in str(err.value)


def test_a_file_that_crashes_asammdf_is_one_line():
    """tests/data/asammdf_segfault.mf4: a file asammdf wrote, four bytes changed (found by
    the fuzzing), on which asammdf 8.8 ends its process with a segmentation fault.  The
    reader's child process takes the crash; the user gets one line."""
    from pathlib import Path

    path = Path(__file__).parent / "data" / "asammdf_segfault.mf4"
    with pytest.raises(MeasuredDataError) as err:
        read_mapped_mdf(path, ColumnMap())
    message = str(err.value)
    assert "\n" not in message and ("asammdf crashed" in message or "MDF" in message)
