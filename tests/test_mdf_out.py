"""Time series written as ASAM MDF4 (damper_emulator.dyno.mdf_writer, ``--format``), read
back by asammdf (independent of the writer's code) and by the project's own readers."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from asammdf import MDF
from rosbags_reader import read_bag

from damper_emulator import topics
from damper_emulator.dyno.mdf_writer import MdfChannel, MdfGroup, write_mdf, write_measured_mdf
from damper_emulator.dyno.measured import read_measured_csv
from damper_emulator.dyno.measured_bag import read_measured
from damper_emulator.recording import read_recording
from damper_emulator.recording_mdf import write_recording_mdf

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "damper_hil.cli"]


def _signals():
    rng = np.random.default_rng(5)
    t = np.arange(3000) * 1e-3 + 0.25
    x = 0.02 * np.sin(2 * np.pi * 1.5 * t)
    v = np.gradient(x, t)
    f = 1800.0 * v + rng.normal(0.0, 3.0, t.size)
    temperature = 25.0 + 0.01 * np.arange(t.size) / t.size
    return t, x, v, f, temperature


def test_measured_data_as_mdf4_carry_units_and_read_back_to_the_bit(tmp_path):
    t, x, v, f, temperature = _signals()
    path = write_measured_mdf(tmp_path / "sine.mf4", t, x, f, v, temperature,
                              comment="a sine on the dyno")
    with MDF(path) as mdf:
        assert "a sine on the dyno" in mdf.header.comment
        for name, values, unit in (("displacement", x, "m"), ("velocity", v, "m/s"),
                                   ("force", f, "N"), ("temperature", temperature, "degC")):
            signal = mdf.get(name)
            assert signal.unit == unit and signal.comment, name
            assert np.array_equal(signal.samples, values), name
            assert np.array_equal(signal.timestamps, t), name
    # the project's reader, without a column map: the same numbers, where a CSV keeps 9
    # significant digits; the time as recorded, as the CSV twin reads it (a series' files
    # on one clock keep their places)
    data = read_measured(path)
    for name, values in (("time", t), ("displacement", x), ("velocity", v), ("force", f),
                         ("temperature", temperature)):
        assert np.array_equal(getattr(data, name), values), name


def test_a_state_and_a_raw_counter_show_through_their_conversions(tmp_path):
    t = np.arange(5) * 1e-3
    path = write_mdf(tmp_path / "run.mf4", [MdfGroup(t, [
        MdfChannel("enable", np.array([0, 1, 1, 0, 1], dtype=np.uint8), "", "enable",
                   states={0: "disabled", 1: "enabled"}),
        MdfChannel("clock", np.array([5, 10, 15, 20, 25], dtype=np.int64) * 10**6, "s",
                   "a clock in ns", linear=(1e-9, 0.0)),
    ], "a group")], "what wrote it")
    with MDF(path) as mdf:
        assert mdf.get("enable").samples.tolist() == [b"disabled", b"enabled", b"enabled",
                                                      b"disabled", b"enabled"]
        assert mdf.get("enable", raw=True).samples.tolist() == [0, 1, 1, 0, 1]
        assert np.allclose(mdf.get("clock").samples, [0.005, 0.01, 0.015, 0.02, 0.025])
        assert mdf.get("clock", raw=True).samples.dtype.kind == "i"
        assert mdf.groups[0].channel_group.comment == "a group"


def test_a_channel_of_another_length_or_a_name_used_twice_is_refused(tmp_path):
    t = np.arange(4.0)
    with pytest.raises(ValueError, match="shape"):
        write_mdf(tmp_path / "a.mf4", [MdfGroup(t, [MdfChannel("x", np.zeros(3))])], "")
    with pytest.raises(ValueError, match="distinct"):
        write_mdf(tmp_path / "b.mf4", [MdfGroup(t, [MdfChannel("x", np.zeros(4))]),
                                       MdfGroup(t, [MdfChannel("x", np.zeros(4))])], "")
    assert not list(tmp_path.iterdir())


def test_a_recorded_bag_as_mdf4_is_the_bag_rosbags_reads(tmp_path):
    bag = ROOT / "bags" / "demo_5s"
    path = write_recording_mdf(read_recording(bag), tmp_path / "demo.mf4", "the sample bag")
    msgs = read_bag(bag)
    with MDF(path) as mdf:
        assert [g.channel_group.comment for g in mdf.groups][:3] == [
            topics.STATE, topics.FORCE, topics.RIDE_STATE]
        recorded = sorted(msgs[topics.FORCE], key=lambda m: m[0])
        stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                           for _, m in recorded])
        force = mdf.get("force")
        assert np.array_equal(force.samples, [m.effort[0] for _, m in recorded])
        assert np.allclose(np.diff(force.timestamps), np.diff(stamps) * 1e-9, atol=1e-9)
        assert np.array_equal(mdf.get("stroke").samples,
                              [m.position[0] for _, m in sorted(msgs[topics.STATE],
                                                                key=lambda m: m[0])])
        assert mdf.get("dtl").unit == "N" and "NO_INPUT" in mdf.get("status").comment


def test_the_dyno_writes_csv_mdf4_or_both_and_every_reader_takes_them(tmp_path):
    both, mf4 = tmp_path / "both", tmp_path / "mf4"
    for out, fmt in ((both, "both"), (mf4, "mf4")):
        r = subprocess.run([*CLI, "dyno", "--protocol", "sine", "--frequency", "2",
                            "--cycles", "2", "--out", str(out), "--format", fmt,
                            "--no-plot"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in both.iterdir()) == ["dyno.json", "sine_2hz.csv",
                                                      "sine_2hz.mf4"]
    assert sorted(p.name for p in mf4.iterdir()) == ["dyno.json", "sine_2hz.mf4"]
    csv, mdf = read_measured_csv(both / "sine_2hz.csv"), read_measured(both / "sine_2hz.mf4")
    for name in ("time", "displacement", "velocity", "force"):
        assert np.allclose(getattr(mdf, name), getattr(csv, name), rtol=1e-8, atol=1e-12)
    # (two runs, not one: the first process of a fresh numba cache compiles the kernels,
    # the second loads them, and the two differ in the last bits, some 1e-15 relative)
    assert np.allclose(read_measured(mf4 / "sine_2hz.mf4").force, mdf.force, rtol=1e-12,
                       atol=1e-9)
    r = subprocess.run([*CLI, "validate", "--params", str(ROOT / "config" / "sport.yaml"),
                        str(mf4 / "sine_2hz.mf4")], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "sine_2hz.mf4" in r.stdout + r.stderr
