"""TDMS files as measured data (damper_emulator/dyno/tdms.py): written here by nptdms's
own writer, with renamed channels in other units (inches, pounds-force, degF, LabVIEW's
unit_string property), read through a column map to the project's CSV reading of the
same data, and the same identification."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

nptdms = pytest.importorskip("nptdms")
from measured_support import assert_same_identification, protocol_records  # noqa: E402
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter  # noqa: E402

from damper_emulator.dyno.column_map import ColumnMap, ColumnMapError  # noqa: E402
from damper_emulator.dyno.measured import MeasuredData, MeasuredDataError  # noqa: E402
from damper_emulator.dyno.measured_bag import read_measured  # noqa: E402
from damper_emulator.dyno.tdms import read_mapped_tdms  # noqa: E402

INCH, LBF = 0.0254, 4.4482216152605
MAP = ColumnMap(columns={"displacement": "Dyno/Pos", "force": "Load", "temperature": "Oil"},
                displacement_sign=-1.0)


def write_tdms(path: Path, t: np.ndarray, x: np.ndarray, f: np.ndarray,
               temperature: np.ndarray, stamps: bool = False) -> Path:
    """The record as a LabVIEW dyno writes it: one group, renamed channels in other units
    (a unit_string each), compression-positive displacement, the time as the force
    channel's waveform increment (or, with ``stamps``, a channel of TDMS time stamps)."""
    dt = float(t[1] - t[0])
    channels = [
        ChannelObject("Dyno", "Load", f / LBF, properties={
            "unit_string": "lbf", "wf_increment": dt, "wf_start_offset": 0.0}),
        ChannelObject("Dyno", "Pos", -x / INCH, properties={"unit_string": "in"}),
        ChannelObject("Dyno", "Oil", temperature * 9 / 5 + 32,
                      properties={"unit_string": "degF"}),
        ChannelObject("Other", "Load", np.zeros(3)),      # a second 'Load', elsewhere
    ]
    if stamps:
        start = np.datetime64("2025-11-14T20:07:10.531160")
        ns = np.round(t * 1e9).astype("timedelta64[ns]")
        channels.append(ChannelObject("Dyno", "Stamp", start + ns))
    with TdmsWriter(path) as writer:
        writer.write_segment([RootObject(), GroupObject("Dyno"), GroupObject("Other"),
                              *channels])
    return path


def _record(n: int = 2001) -> tuple[np.ndarray, ...]:
    t = np.arange(n) / 1000.0
    x = 0.02 * np.sin(2 * np.pi * 2 * t)
    v = 0.02 * 2 * np.pi * 2 * np.cos(2 * np.pi * 2 * t)
    return t, x, 3000.0 * v + 40.0 * np.tanh(v / 0.01) - 300.0, 25.0 + 10.0 * t


def test_a_tdms_file_reads_as_its_si_record(tmp_path):
    """(The project's CSV writer rounds to 9 digits, a TDMS file keeps every bit: the
    reference is the record itself.)"""
    t, x, f, temp = _record()
    plain = MeasuredData(t, x, f, temperature=temp)
    # 'Load' is in both groups: a plain name is refused, Group/Channel read
    path = write_tdms(tmp_path / "run.tdms", t, x, f, temp)
    with pytest.raises(MeasuredDataError, match="in 2 groups"):
        read_mapped_tdms(path, MAP)
    cmap = ColumnMap(columns={**MAP.columns, "force": "Dyno/Load"}, displacement_sign=-1.0)
    data = read_mapped_tdms(path, cmap)
    np.testing.assert_allclose(data.time, plain.time, rtol=0, atol=1e-12)
    for q in ("displacement", "force", "temperature"):
        np.testing.assert_allclose(getattr(data, q), getattr(plain, q), rtol=1e-12,
                                   atol=1e-12, err_msg=q)
    stamped = write_tdms(tmp_path / "stamped.tdms", t, x, f, temp, stamps=True)
    data = read_mapped_tdms(stamped, ColumnMap(columns={**cmap.columns, "time": "Stamp"},
                                               displacement_sign=-1.0))
    # nptdms gives TDMS stamps (2^-64 s) to the microsecond, cut, not rounded
    np.testing.assert_allclose(data.time, plain.time, rtol=0, atol=1.01e-6)


def test_an_identification_from_a_tdms_file_is_the_one_from_its_si_record(
        tmp_path, sport_cfg, sport_model):
    cmap = ColumnMap(columns={**MAP.columns, "force": "Dyno/Load"}, displacement_sign=-1.0)
    si, tdms = [], []
    for name, t, x, f, temp in protocol_records(sport_model, 4):
        si.append(MeasuredData(t, x, f, temperature=temp))
        tdms.append(read_mapped_tdms(write_tdms(tmp_path / f"{name}.tdms", t, x, f, temp),
                                     cmap))
    assert_same_identification(si, tdms, sport_cfg)


def test_bad_tdms_files_are_one_line(tmp_path):
    t, x, f, temp = _record(200)
    path = write_tdms(tmp_path / "run.tdms", t, x, f, temp)
    cases = [(ColumnMap(columns={"displacement": "Dyno/Stroke", "force": "Dyno/Load"}),
              MeasuredDataError, r"no channel 'Dyno/Stroke' \(have: Dyno/Load"),
             (ColumnMap(columns={"displacement": "Dyno/Oil", "force": "Dyno/Load"}),
              ColumnMapError, "'degF' is not a unit of displacement")]
    for cmap, kind, words in cases:
        with pytest.raises(kind, match=words) as err:
            read_mapped_tdms(path, cmap)
        assert "\n" not in str(err.value)
    junk = tmp_path / "junk.tdms"
    for blob, words in ((b"not a tdms file, " * 8, "not a TDMS file nptdms can read"),
                        (b"TDSm" + bytes(range(60)), "no channel 'Dyno/Pos' \\(have: none")):
        junk.write_bytes(blob)
        with pytest.raises(MeasuredDataError, match=words) as err:
            read_measured(junk, MAP)
        assert "\n" not in str(err.value)


def test_the_command_line_reads_a_tdms_file(tmp_path):
    from damper_hil.cli import main

    t, x, f, temp = _record()
    path = write_tdms(tmp_path / "run.tdms", t, x, f, temp)
    params = str(Path(__file__).resolve().parents[1] / "config" / "sport.yaml")
    assert main(["validate", "--params", params, str(path), "--json", str(tmp_path / "v.json"),
                 "--displacement-sign", "-1", "--columns", "displacement=Dyno/Pos",
                 "force=Dyno/Load", "temperature=Oil"]) == 0
