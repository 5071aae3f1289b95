"""Outputs written atomically, as sets (damper_emulator/outputs.py), and names that are not
UTF-8 kept end to end: the module on real files and folders, then the commands that use it
(tune, identify; the fleet's are in tests/test_fleet.py).

What a user must be able to count on: a run that fails or is interrupted, at any moment,
leaves the previous result whole or nothing, and no temporary file; a rerun replaces a
folder as a whole; a location that cannot be written is one line before any work; nothing
the user owns is overwritten or deleted.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from damper_emulator import outputs as out_mod
from damper_emulator.errors import ESCAPE, printable
from damper_emulator.outputs import MARKER, OutputError, Outputs, write_text

#: a folder name that is not UTF-8 (``café`` in Latin-1), as Python holds it (PEP 383)
LATIN1 = os.fsdecode(b"caf\xe9")


def _tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (relative name → content)."""
    return {p.relative_to(root).as_posix(): p.read_bytes()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _partials(folder: Path) -> list[str]:
    return [p.name for p in folder.rglob("*") if ".partial-" in p.name]


def _first_run(tmp_path: Path) -> tuple[Path, Path]:
    """A committed folder (two files, one in a sub-folder) and a committed file."""
    with Outputs() as out:
        report = out.folder(tmp_path / "report")
        params = out.file(tmp_path / "fitted.yaml")
        (report / "sub").mkdir()
        (report / "sub" / "a.txt").write_text("first a")
        (report / "b.txt").write_text("first b")
        params.write_text("first params")
    return tmp_path / "report", tmp_path / "fitted.yaml"


def test_a_committed_set_is_in_place_and_marked(tmp_path):
    said: list[str] = []
    with Outputs(say=said.append) as out:
        report = out.folder(tmp_path / "new" / "report")
        params = out.file(tmp_path / "new" / "fitted.yaml")
        # nothing is in place before the end
        assert not (tmp_path / "new" / "report").exists()
        assert not (tmp_path / "new" / "fitted.yaml").exists()
        (report / "x.png").write_bytes(b"png")
        params.write_text("p")
        assert out.final(report / "x.png") == tmp_path / "new" / "report" / "x.png"
    assert _tree(tmp_path / "new") == {"fitted.yaml": b"p", "report/x.png": b"png",
                                       f"report/{MARKER}": out_mod._MARKER_TEXT.encode()}
    assert said[0] == f"wrote {tmp_path / 'new' / 'fitted.yaml'}"
    assert said[1].startswith(f"wrote {tmp_path / 'new' / 'report'}/ (1 file: x.png)")
    assert not _partials(tmp_path)


@pytest.fixture
def python_sigint():
    """Python's own SIGINT handler (KeyboardInterrupt) for the test: a suite started in the
    background of a shell without job control inherits SIGINT ignored, and Python then
    installs no handler of its own."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("how", ["exception", "sigint"])
def test_a_run_that_fails_or_is_interrupted_leaves_the_previous_result_whole(tmp_path, how,
                                                                              python_sigint):
    report, params = _first_run(tmp_path)
    before = _tree(tmp_path)
    # the with-block's exit on the failure is what is tested
    with pytest.raises(KeyboardInterrupt if how == "sigint" else RuntimeError), \
            Outputs() as out:  # noqa: PT012
        new_report = out.folder(report)
        new_params = out.file(params)
        (new_report / "b.txt").write_text("second, half writ")
        new_params.write_text("second")
        if how == "sigint":
            signal.raise_signal(signal.SIGINT)   # Python's handler: KeyboardInterrupt
        raise RuntimeError("the work failed")
    assert _tree(tmp_path) == before
    assert not _partials(tmp_path)


def test_a_signal_during_the_renames_waits_until_the_set_is_in_place(tmp_path, monkeypatch,
                                                                    python_sigint):
    """SIGINT arriving between two renames of a set: the set is completed first, then
    the interrupt is delivered."""
    report, params = _first_run(tmp_path)
    real_replace = os.replace
    delivered: list[int] = []

    def replace_then_signal(src, dst):
        real_replace(src, dst)
        if not delivered:
            delivered.append(1)
            signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(out_mod.os, "replace", replace_then_signal)
    # the with-block's exit on the interrupt is what is tested
    with pytest.raises(KeyboardInterrupt), Outputs() as out:  # noqa: PT012
        new_params = out.file(params)
        new_report = out.folder(report)
        new_params.write_text("second params")
        (new_report / "c.txt").write_text("second c")
    assert delivered
    assert _tree(tmp_path) == {"fitted.yaml": b"second params", "report/c.txt": b"second c",
                               f"report/{MARKER}": out_mod._MARKER_TEXT.encode()}


@pytest.mark.parametrize("exchange", [True, False])
def test_a_rerun_replaces_the_folder_as_a_whole(tmp_path, monkeypatch, exchange):
    """No file of the earlier run survives beside the new ones (an earlier tune's
    designs/*.yaml), whether the system swaps the folders in one step or not."""
    if not exchange:
        monkeypatch.setattr(out_mod, "_exchange", lambda a, b: False)
    report, _ = _first_run(tmp_path)
    with Outputs() as out:
        new = out.folder(report)
        (new / "b.txt").write_text("second b")
    assert _tree(report) == {"b.txt": b"second b", MARKER: out_mod._MARKER_TEXT.encode()}
    assert not _partials(tmp_path) and sorted(p.name for p in tmp_path.iterdir()) == \
        ["fitted.yaml", "report"]


def test_the_system_swaps_folders_in_one_step_here(tmp_path):
    """renameat2(RENAME_EXCHANGE) works on this machine's file system (else the fallback
    of the test above is what runs)."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "x").write_text("a")
    if not out_mod._exchange(tmp_path / "a", tmp_path / "b"):
        pytest.skip("no renameat2(RENAME_EXCHANGE) here")
    assert (tmp_path / "b" / "x").read_text() == "a" and not (tmp_path / "a" / "x").exists()


def test_locations_are_checked_before_the_work(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "data.csv").write_text("1,2\n")
    (tmp_path / "a_file").write_text("x")
    (tmp_path / "empty").mkdir()
    cases = [
        (lambda o: o.folder(tmp_path / "mine"), "holds files damper-hil did not write"),
        (lambda o: o.folder(tmp_path / "a_file"), "is a file"),
        (lambda o: o.file(tmp_path / "mine"), "is a folder"),
        (lambda o: o.file(tmp_path / "a_file" / "x.json"), "not a folder"),
        (lambda o: o.folder(tmp_path / "a_file" / "report"), "not a folder"),
    ]
    for register, needle in cases:
        out = Outputs()
        with pytest.raises(OutputError, match=needle):
            register(out)
        out.discard()
    assert (tmp_path / "mine" / "data.csv").read_text() == "1,2\n"   # never touched
    with Outputs() as out:                                   # an empty folder is fine
        (out.folder(tmp_path / "empty") / "r.txt").write_text("r")
    assert (tmp_path / "empty" / "r.txt").is_file()
    assert not _partials(tmp_path)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_a_read_only_folder_is_one_line(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="cannot write"):
            Outputs().file(ro / "x.json")
    finally:
        ro.chmod(0o700)


def test_an_unwritable_place_is_one_line_even_for_root(tmp_path):
    """/proc refuses new files to everyone (root included)."""
    with pytest.raises(OutputError, match="cannot"):
        Outputs().file(Path("/proc/damper-hil-test.json"))


def test_an_input_is_never_an_output_or_inside_one(tmp_path):
    report, params = _first_run(tmp_path)
    with pytest.raises(OutputError, match="is also an input"):
        Outputs(inputs=[params]).file(params)
    with pytest.raises(OutputError, match="holds the input"):
        Outputs(inputs=[report / "b.txt", None]).folder(report)
    o = Outputs()
    o.file(tmp_path / "x.json")
    with pytest.raises(OutputError, match="two outputs"):
        o.file(tmp_path / "." / "x.json")


def test_a_file_inside_a_folder_output_goes_with_it(tmp_path):
    """validate's default JSON lies in its --report folder: one set."""
    target = tmp_path / "report"
    with Outputs() as out:
        folder = out.folder(target)
        (out.file(target / "validation.json")).write_text("{}")
        out.file(target / "sub" / "v2.json").write_text("{}")
        assert (folder / "validation.json").is_file()
    assert sorted(_tree(target)) == [MARKER, "sub/v2.json", "validation.json"]
    out = Outputs()
    out.file(tmp_path / "late" / "x.json")
    with pytest.raises(RuntimeError, match="bug: the folder output"):
        out.folder(tmp_path / "late")           # its file's path was already handed out
    out.discard()
    assert not _partials(tmp_path)


def test_temporary_copies_of_a_killed_run_are_removed_by_the_next(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    stale_file = out_mod._staging(tmp_path / "r.json", pid)
    stale_dir = out_mod._staging(tmp_path / "report", pid)
    stale_file.write_text("half")
    stale_dir.mkdir()
    (stale_dir / "x.png").write_bytes(b"half")
    other = tmp_path / ".notes.partial-1.txt"      # not a staging name of these outputs
    other.write_text("mine")
    with Outputs() as out:
        out.file(tmp_path / "r.json").write_text("{}")
        out.folder(tmp_path / "report")
    assert not stale_file.exists() and not stale_dir.exists() and other.exists()


def test_names_that_are_not_utf8_are_kept_and_written_escaped(tmp_path):
    folder = tmp_path / LATIN1
    with Outputs() as out:
        staged = out.folder(folder)
        (staged / "rows.csv").write_bytes(f"id\n{LATIN1}\n".encode("utf-8", ESCAPE))
    assert os.listdir(os.fsencode(tmp_path)) == [b"caf\xe9"]      # the name as given
    assert (folder / "rows.csv").read_text(encoding="utf-8") == "id\ncaf\\xe9\n"
    write_text(tmp_path / "t.txt", f"{LATIN1} and café")
    assert (tmp_path / "t.txt").read_text(encoding="utf-8") == "caf\\xe9 and café"
    assert printable(f"{folder}") == f"{tmp_path}/caf\\xe9"


# --------------------------------------------------------------------------------------
# the commands


@pytest.mark.slow
def test_tune_checks_out_before_the_search_and_replaces_it_whole(tmp_path, cli, monkeypatch):
    """An OUT that cannot be written is one line before any design is computed; a rerun
    leaves no design file of the earlier run that its pareto.json does not name; an
    interrupt while writing leaves the earlier result byte for byte."""
    import json

    small = ["--designs", 4, "--refine-rounds", 0, "--length", 100, "--road-classes", "A",
             "--workers", 1]
    (tmp_path / "a_file").write_text("x")
    res = cli("tune", "--out", tmp_path / "a_file" / "out", *small)
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0, res.stderr
    assert "not a folder" in res.stderr                      # and no "tuning on ..." line
    out = tmp_path / "out"
    # 8 designs, then 4: the first run's front holds designs numbered above 4, which the
    # second cannot name
    assert cli("tune", "--out", out, *small, "--seed", 1, "--designs", 8).returncode == 0
    first = _tree(out)
    assert any(int(name[-9:-5]) > 4 for name in first if name.startswith("designs/"))
    res = cli("tune", "--out", out, *small, "--seed", 2)
    assert res.returncode == 0, res.stderr
    doc = json.loads((out / "pareto.json").read_text())
    named = {d["params_file"] for d in doc["designs"]}
    on_disk = {f"designs/{p.name}" for p in (out / "designs").iterdir()}
    assert on_disk <= named and doc["evaluated"] == 5
    second = _tree(out)

    from damper_hil.tune import report

    real = report._write_csv

    def interrupted(path, *args):
        real(path, *args)
        path.write_text(path.read_text()[:10])   # half a file, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "_write_csv", interrupted)
    res = cli("tune", "--out", out, *small, "--seed", 3)
    assert res.returncode == 130, res.stderr
    assert _tree(out) == second and not _partials(tmp_path)


def test_identify_checks_its_outputs_before_identifying(tmp_path, cli):
    (tmp_path / "a_file").write_text("x")
    res = cli("identify", "--quasi-static", "missing_qs.csv", "--chirp", "missing.csv",
              "--out", tmp_path / "a_file" / "p.yaml")
    assert res.returncode == 2 and "not a folder" in res.stderr, res.stderr
    assert res.stderr.strip().count("\n") == 0
    res = cli("identify", "--quasi-static", tmp_path / "a_file", "--chirp", "c.csv",
              "--out", tmp_path / "a_file")
    assert res.returncode == 2 and "is also an input" in res.stderr, res.stderr
    assert (tmp_path / "a_file").read_text() == "x" and not _partials(tmp_path)


def test_a_data_file_whose_name_is_not_utf8_is_validated_and_plotted(tmp_path, cli):
    """The name reaches titles, legends and tick labels: every plot is drawn with it
    escaped (the font renderer refuses lone surrogates), the JSON keeps it."""
    import json

    import numpy as np

    from damper_emulator.dyno.measured import write_measured_csv

    t = np.arange(1500) / 1000.0
    x = 0.02 * np.sin(2 * np.pi * 2.0 * t)
    v = 0.02 * 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t)
    data = tmp_path / f"sine_{LATIN1}.csv"
    write_measured_csv(data, t, x, 8000.0 * v + 400.0, velocity=v)
    res = cli("validate", "--params", "config/sport.yaml", data, "--report", tmp_path / "r")
    assert res.returncode == 0, res.stderr
    assert "sine_caf\\xe9.csv" in res.stdout
    doc = json.loads((tmp_path / "r" / "validation.json").read_text())
    assert list(doc["files"]) == [f"sine_{LATIN1}.csv"]
    pngs = sorted(p.name for p in (tmp_path / "r").glob("*.png"))
    assert pngs == [f"validate_sine_{LATIN1}.png", "validation_summary.png"]
