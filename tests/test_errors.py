"""One error family (damper_emulator.errors) and how the command line reports it: a user
error is one line and exit 2, a failure of the environment one line and exit 1, a bug one
line, a hint and exit 1, and ``--debug`` shows the traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from can_bridge.bus import CanBusError
from can_bridge.dbc import DbcError
from can_bridge.dyno_client import OverCanError
from damper_emulator.bag import BagError
from damper_emulator.dyno.measured import MeasuredDataError
from damper_emulator.errors import DamperHilError, UserError, one_line
from damper_emulator.identify.quasi_static import IdentificationError
from damper_emulator.model.valve_table import ValveTableError
from damper_emulator.ros.readiness import NotReadyError
from damper_emulator.schema import ParameterError
from damper_hil import cli
from damper_hil.cli import validate as validate_cmd
from damper_hil.cli.common import CliError
from damper_hil.engine import EngineError
from damper_hil.hil_demo import DemoError
from ride_sim.road import RoadError

USER = (ParameterError, MeasuredDataError, IdentificationError, ValveTableError, BagError,
        RoadError, DbcError, CanBusError, CliError, EngineError)
ENVIRONMENT = (NotReadyError, DemoError, OverCanError)


@pytest.mark.parametrize("cls", USER)
def test_user_errors_are_one_branch_and_still_value_errors(cls):
    assert issubclass(cls, UserError) and issubclass(cls, ValueError)


@pytest.mark.parametrize("cls", ENVIRONMENT)
def test_environment_failures_are_in_the_family_but_not_user_errors(cls):
    assert issubclass(cls, DamperHilError) and not issubclass(cls, UserError)


def test_one_line():
    assert one_line(ValueError("a\n   b\tc ")) == "a b c"
    assert one_line(KeyError(), with_type=True) == "KeyError"
    assert one_line(OSError("disk  full"), with_type=True) == "OSError: disk full"
    assert one_line("") == "unknown error"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "damper_hil.cli", *args],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.slow
def test_a_user_error_is_one_line_and_exit_2(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,displacement\n0,0\n")
    r = _run("validate", "--params", "config/sport.yaml", str(bad))
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("damper-hil: error: ") and "force" in lines[0]
    assert "Traceback" not in r.stderr


def _boom(args):
    return 1 / 0          # a bug: nothing the user gave can cause it


def test_a_bug_is_reported_as_a_bug_and_debug_shows_the_traceback(monkeypatch, capsys):
    monkeypatch.setattr(validate_cmd, "run", _boom)
    assert cli.main(["validate", "--params", "config/sport.yaml", "x.csv"]) == 1
    err = capsys.readouterr().err
    assert "internal error: ZeroDivisionError: division by zero" in err
    assert "bug in damper-hil" in err and "--debug" in err and "Traceback" not in err
    with pytest.raises(ZeroDivisionError):
        cli.main(["validate", "--debug", "--params", "config/sport.yaml", "x.csv"])


def test_an_environment_failure_is_one_line_and_exit_1(monkeypatch, capsys):
    def not_ready(args):
        raise NotReadyError("damper_emulator did not become active within 1 s")
    monkeypatch.setattr(validate_cmd, "run", not_ready)
    assert cli.main(["validate", "--params", "config/sport.yaml", "x.csv"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["damper-hil: error: damper_emulator did not become active within 1 s"]
