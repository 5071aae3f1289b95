"""``damper-hil fleet`` on real Dask: a ``distributed.LocalCluster`` of worker processes,
the synchronous scheduler, and a ``dask scheduler`` with two ``dask worker`` processes
started as separate commands, one of them killed in the middle of the run.

The data are a virtual production batch (``fleet-example``, short protocol) whose truth
differs in model form from the emulator's model (smooth friction, displacement noise) and
carries seeded defects; the identified parameters are checked against the batch's
``truth.json``, the flags against its defects, and the tables are read back with
``pyarrow`` and ``csv``.
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from damper_emulator.diagnose.truth import REALISTIC
from damper_emulator.dyno.protocols import QuasiStatic
from damper_emulator.params import load_config
from damper_hil.engine import EngineError, command_cluster, open_engine
from damper_hil.fleet.example import write_example
from damper_hil.fleet.inputs import find_dampers
from damper_hil.fleet.runner import RESULT_FILE, run_fleet
from damper_hil.fleet.scatter import DEFECTS

pytestmark = pytest.mark.slow

#: the batch of the tests: 8 units, so that every seeded defect (units 3, 5, 8) is in it
UNITS = 8


def _cli(*args: object, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "damper_hil.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=600, **kw)


@pytest.fixture(scope="module")
def batch(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fleet") / "batch"
    write_example(out, load_config(), UNITS, seed=1, short=True, say=lambda m: None)
    return out


def _truth(batch: Path) -> dict:
    return json.loads((batch / "truth.json").read_text())["units"]


def _parquet_rows(path: Path) -> list[dict]:
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pylist()


def test_local_cluster_identifies_every_unit_and_flags_the_seeded_defects(batch, tmp_path):
    out = tmp_path / "out"
    with open_engine(workers=2) as engine:
        assert "local Dask cluster, 2 worker processes" in engine.description
        run = run_fleet(batch, out, engine, say=lambda m: None)
    truth = _truth(batch)
    rows = {r["id"]: r for r in _parquet_rows(out / "results.parquet")}
    assert sorted(rows) == sorted(truth) and all(r["status"] == "ok" for r in rows.values())
    # two worker processes shared the work
    assert len({r["worker"] for r in rows.values()}) == 2
    for uid, t in truth.items():
        r = rows[uid]
        # the gas spring against the truth's (the quasi-static test determines it)
        assert r["gas_pressure_static_pa"] == pytest.approx(t["gas_pressure_static_pa"],
                                                            rel=0.02)
        assert r["gas_volume_static_m3"] == pytest.approx(t["gas_volume_static_m3"],
                                                          rel=0.03)
        assert r["gas_pressure_static_pa_se"] > 0
        # the truth's friction is F tanh(v / v_f): the quasi-static test, at constant speed
        # v_qs, sees F tanh(v_qs / v_f), which the model's Coulomb friction takes
        seen = t["friction_force_n"] * math.tanh(QuasiStatic().velocity_m_s
                                                 / REALISTIC.friction_smoothing_m_s)
        if t["defect"] != "valve_lag":  # (the lag, which the model lacks, biases it)
            assert r["friction_force_n"] == pytest.approx(seen, rel=0.05)
    flags = {uid: set(filter(None, rows[uid]["flags"].split(";"))) for uid in rows}
    defects = {f"unit_{k:02d}": name for k, (name, _) in DEFECTS.items()}
    assert "low_gas_charge" in flags[next(u for u, d in defects.items()
                                      if d == "low_gas_charge")]
    assert "high_friction" in flags[next(u for u, d in defects.items() if d == "high_friction")]
    # the lag is no parameter of the model: the validation shows it
    assert "poor_fit" in flags[next(u for u, d in defects.items() if d == "valve_lag")]
    for uid, f in flags.items():  # the units without a defect are not flagged
        assert (not f) == (uid not in defects), (uid, f)
    # the CSV holds the same rows and values
    with (out / "results.csv").open() as fh:
        csv_rows = {r["id"]: r for r in csv.DictReader(fh)}
    for uid, r in rows.items():
        assert float(csv_rows[uid]["friction_force_n"]) == pytest.approx(
            r["friction_force_n"], rel=1e-12)
    # the per-damper files are those of the single commands: identified.yaml loads
    cfg = load_config(out / "unit_01" / "identified.yaml")
    assert cfg.damper.gas_pressure_static_pa == pytest.approx(
        rows["unit_01"]["gas_pressure_static_pa"], rel=1e-9)
    assert set(json.loads((out / "unit_01" / "validation.json").read_text())["files"]) == {
        "sine_1hz.csv", "sine_3hz.csv", "sine_12hz.csv"}
    assert run.resumed == []


def _bad_batch(batch: Path, dest: Path) -> Path:
    """Two good units and three bad folders."""
    for uid in ("unit_01", "unit_02"):
        shutil.copytree(batch / uid, dest / uid)
    nan = shutil.copytree(batch / "unit_01", dest / "broken_nan")
    lines = (nan / "chirp.csv").read_text().splitlines()
    cells = lines[100].split(",")
    cells[2] = "nan"
    lines[100] = ",".join(cells)
    (nan / "chirp.csv").write_text("\n".join(lines) + "\n")
    missing = shutil.copytree(batch / "unit_01", dest / "no_sines")
    for f in missing.glob("sine_*.csv"):
        f.unlink()
    base = shutil.copytree(batch / "unit_01", dest / "bad_base")
    (base / "base.yaml").write_text((base / "base.yaml").read_text().replace(
        "gas_gamma: 1.4", "gas_gamma: 7.0"))
    return dest


def test_bad_input_is_one_row_in_error_and_the_fleet_goes_on(batch, tmp_path):
    data = _bad_batch(batch, tmp_path / "data")
    out = tmp_path / "out"
    res = _cli("fleet", data, "--out", out, "--workers", "1")
    assert res.returncode == 0, res.stderr
    assert "dask synchronous scheduler" in res.stderr
    rows = {r["id"]: r for r in _parquet_rows(out / "results.parquet")}
    assert rows["unit_01"]["status"] == rows["unit_02"]["status"] == "ok"
    reasons = {uid: rows[uid]["reason"] for uid in ("broken_nan", "no_sines", "bad_base")}
    assert all(rows[uid]["status"] == "error" for uid in reasons)
    assert "chirp.csv" in reasons["broken_nan"] and "NaN" in reasons["broken_nan"].replace(
        "nan", "NaN")
    assert "sine_*.csv" in reasons["no_sines"]
    assert "gas_gamma" in reasons["bad_base"]
    assert all("\n" not in r for r in reasons.values())
    assert "2 of 5 dampers finished, 3 in error" in res.stdout
    summary = (out / "summary.md").read_text()
    assert "## Dampers in error" in summary and "broken_nan" in summary


def test_a_rerun_on_the_same_out_does_not_redo_finished_dampers(batch, tmp_path):
    data = tmp_path / "data"
    for uid in ("unit_01", "unit_02", "unit_04"):
        shutil.copytree(batch / uid, data / uid)
    out = tmp_path / "out"
    with open_engine(workers=1) as engine:
        run_fleet(data, out, engine, say=lambda m: None)
        first = {uid: (out / uid / RESULT_FILE).stat().st_mtime_ns
                 for uid in ("unit_01", "unit_02")}
        (out / "unit_04" / RESULT_FILE).unlink()  # as if killed before it finished
        said: list[str] = []
        run = run_fleet(data, out, engine, say=said.append)
    assert sorted(run.resumed) == ["unit_01", "unit_02"]
    assert "2 of 3 dampers already finished, 1 to run" in said[0]
    assert {uid: (out / uid / RESULT_FILE).stat().st_mtime_ns for uid in first} == first
    assert (out / "unit_04" / RESULT_FILE).exists()
    assert [r["status"] for r in run.rows] == ["ok"] * 3


def test_diagnose_in_the_fleet_names_the_seeded_valve_lag(batch, tmp_path):
    lag = next(f"unit_{k:02d}" for k, (name, _) in DEFECTS.items() if name == "valve_lag")
    data = tmp_path / "data"
    for uid in ("unit_01", lag):
        shutil.copytree(batch / uid, data / uid)
    out = tmp_path / "out"
    # one candidate: the lag is named on its damper and not significant on the other
    res = _cli("fleet", data, "--out", out, "--workers", "2", "--diagnose",
               "--effects", "valve_lag")
    assert res.returncode == 0, res.stderr
    rows = {r["id"]: r for r in _parquet_rows(out / "results.parquet")}
    assert rows[lag]["diagnosis_family"] == "valve_dynamics"
    assert rows[lag]["diagnosis_rms_after_n"] < 0.2 * rows[lag]["validation_rms_n"]
    assert "diagnosed" in rows[lag]["flags"]
    assert rows["unit_01"]["diagnosis_family"] == "none"
    doc = json.loads((out / lag / "diagnosis.json").read_text())
    tau = doc["effects"][0]["parameters"]["time_constant_s"]
    truth = _truth(batch)[lag]["extensions"]["valve_lag"]["time_constant_s"]
    assert tau == pytest.approx(truth, rel=0.15)
    assert (out / "diagnosis.png").exists()


def _listening_addresses(pids: set[int]) -> set[str]:
    """The IP addresses the processes ``pids`` (and their children) listen on."""
    import psutil

    tree = set(pids)
    for pid in pids:
        with contextlib.suppress(psutil.NoSuchProcess):
            tree |= {c.pid for c in psutil.Process(pid).children(recursive=True)}
    return {c.laddr.ip for c in psutil.net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN and c.pid in tree}


def test_scheduler_and_two_workers_as_commands_one_killed_mid_run(batch, tmp_path):
    """``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1; ``fleet
    --scheduler``; after the first damper is done, a worker that is running a damper's
    task is killed (with its nanny, SIGKILL): every damper still ends with a result."""
    from distributed import Client

    out = tmp_path / "out"
    with command_cluster(tmp_path, 2) as cluster:
        address = cluster.address
        assert address.startswith("tcp://127.0.0.1:")
        # nothing of the cluster listens beyond this machine
        assert _listening_addresses({p.pid for p in (cluster.scheduler, *cluster.workers)}
                                    ) == {"127.0.0.1"}
        fleet = subprocess.Popen([sys.executable, "-m", "damper_hil.cli", "fleet", str(batch),
                                  "--out", str(out), "--scheduler", address],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 300
        while (not list(out.glob(f"*/{RESULT_FILE}")) and fleet.poll() is None
               and time.monotonic() < deadline):
            time.sleep(0.1)
        assert fleet.poll() is None, fleet.communicate()
        # kill a worker that is running a damper's task right now
        with Client(address, timeout="30s") as probe:
            busy: list[str] = []
            while not busy and time.monotonic() < deadline:
                workers = probe.scheduler_info()["workers"]
                busy = [workers[a]["name"] for a, keys in probe.processing().items()
                        if keys and a in workers]
                time.sleep(0.05)
            assert busy
            done_before_kill = {p.parent.name for p in out.glob(f"*/{RESULT_FILE}")}
            victim = cluster.workers[int(str(busy[0])[1:])]
            import psutil

            killed = {victim.pid, *(c.pid for c in psutil.Process(victim.pid).children(
                recursive=True))}
            t_kill = time.time()
            cluster.kill(victim)
        stdout, stderr = fleet.communicate(timeout=600)
        log = (tmp_path / "scheduler.log").read_text()
    assert fleet.returncode == 0, stderr
    assert "(2 workers)" in stderr
    assert len(done_before_kill) < UNITS
    rows = {r["id"]: r for r in _parquet_rows(out / "results.parquet")}
    assert len(rows) == UNITS and all(r["status"] == "ok" for r in rows.values()), [
        (r["id"], r["reason"]) for r in rows.values() if r["status"] != "ok"]
    assert f"{UNITS} of {UNITS} dampers finished" in stdout
    # what was left, the killed worker's task among it, the survivor did: nothing the
    # killed worker did finished after the kill (its task in flight was run again)
    by_killed = [r for r in rows.values() if int(r["worker"].rsplit(":", 1)[1]) in killed]
    assert all(r["finished_unix_s"] < t_kill for r in by_killed), (t_kill, by_killed)
    assert any(r["finished_unix_s"] > t_kill for r in rows.values())
    assert "Remove worker" in log


def test_a_local_cluster_listens_on_localhost_only():
    import psutil

    with open_engine(workers=2) as engine:
        pids = {psutil.Process().pid}
        assert _listening_addresses(pids) == {"127.0.0.1"}
        assert engine.workers == 2


def test_engine_errors_are_one_line(tmp_path):
    with pytest.raises(EngineError, match="cannot reach the Dask scheduler"), \
            open_engine(scheduler="tcp://127.0.0.1:9", connect_timeout_s=2):
        pass
    with pytest.raises(EngineError, match="not both"), \
            open_engine(scheduler="tcp://127.0.0.1:9", workers=2):
        pass
    res = _cli("fleet", tmp_path / "nowhere", "--out", tmp_path / "o")
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0
    assert "not a folder" in res.stderr


def test_a_task_that_fails_is_its_outcome_not_the_runs():
    with open_engine(workers=1) as engine:
        out = {o.key: o for o in engine.map_unordered(
            lambda x: 1.0 / x, [("a", 2.0), ("b", 0.0), ("c", 4.0)])}
    assert out["a"].value == 0.5 and out["c"].value == 0.25
    assert isinstance(out["b"].error, ZeroDivisionError)


def test_a_damper_folder_whose_name_is_not_utf8_is_a_row_with_its_name_escaped(
        batch, tmp_path):
    """A folder named ``café`` in Latin-1 (not UTF-8): the fleet finishes, its row's id is
    ``caf\\xe9`` in the CSV, the Parquet file and the summary, no temporary file is left,
    and a rerun resumes it by its real name."""
    data = tmp_path / "data"
    latin1 = os.fsdecode(b"caf\xe9")
    shutil.copytree(batch / "unit_01", data / latin1)
    out = tmp_path / "out"
    for attempt in ("first", "rerun"):
        res = _cli("fleet", data, "--out", out, "--workers", "1")
        assert res.returncode == 0, (attempt, res.stderr)
        assert "Traceback" not in res.stderr
        assert attempt == "rerun" or "caf\\xe9 ok" in res.stderr
        with (out / "results.csv").open(encoding="utf-8") as fh:
            rows = {r["id"]: r for r in csv.DictReader(fh)}
        assert set(rows) == {"caf\\xe9"} and rows["caf\\xe9"]["status"] == "ok"
        assert {r["id"] for r in _parquet_rows(out / "results.parquet")} == set(rows)
        assert (out / "summary.md").read_text(encoding="utf-8").startswith("# Fleet summary")
        assert (out / latin1 / RESULT_FILE).is_file()
        assert not [p for p in out.iterdir() if ".partial-" in p.name or ".tmp" in p.name]
    assert "1 of 1 dampers already finished" in res.stderr


def test_a_damper_whose_tests_are_mdf4_and_tdms_files_is_read_as_its_csvs(batch, tmp_path):
    """A unit's tests as MDF4 (as ``dyno --format mf4`` writes them) and one as TDMS
    (nptdms's writer), beside other files: found by their roles, read through the one
    measured-data reader, and identified as the same unit's CSVs are, to the bit."""
    from nptdms import ChannelObject, TdmsWriter

    from damper_emulator.dyno.mdf_writer import write_measured_mdf
    from damper_emulator.dyno.measured import read_measured_csv

    csv_unit = shutil.copytree(batch / "unit_01", tmp_path / "data" / "csv_unit")
    other = tmp_path / "data" / "lab_unit"
    other.mkdir()
    shutil.copy(csv_unit / "base.yaml", other / "base.yaml")
    (other / "notes.txt").write_text("not a test\n")
    for path in sorted(csv_unit.glob("*.csv")):
        d = read_measured_csv(path)
        if path.stem == "sine_3hz":
            with TdmsWriter(other / "sine_3hz.tdms") as w:
                w.write_segment([ChannelObject("dyno", q, getattr(d, q)) for q in
                                 ("time", "displacement", "velocity", "force")])
        else:
            write_measured_mdf(other / f"{path.stem}.mf4", d.time, d.displacement, d.force,
                               d.velocity, d.temperature)
    (unit,) = [u for u in find_dampers(tmp_path / "data") if u.id == "lab_unit"]
    assert [p.name for p in unit.quasi_static] == ["quasi_static.mf4"]
    assert [p.name for p in unit.chirp] == ["chirp.mf4"]
    assert sorted(p.name for p in unit.validate) == ["sine_12hz.mf4", "sine_1hz.mf4",
                                                     "sine_3hz.tdms"]
    with open_engine(workers=1) as engine:
        run_fleet(tmp_path / "data", tmp_path / "out", engine, say=lambda m: None)
    rows = {r["id"]: r for r in _parquet_rows(tmp_path / "out" / "results.parquet")}
    assert rows["lab_unit"]["status"] == "ok", rows["lab_unit"]
    fitted = [k for k in rows["csv_unit"] if k.endswith("_se")]
    assert len(fitted) >= 10
    for key in (k[:-3] for k in fitted):
        assert rows["lab_unit"][key] == rows["csv_unit"][key], key
    assert rows["lab_unit"]["validation_files"] == 3
    assert rows["lab_unit"]["validation_rms_n"] == pytest.approx(
        rows["csv_unit"]["validation_rms_n"], rel=1e-6)
