"""Shared fixtures: the paper's 'sport' damper; one cold run of the demo; the command
line run in this process.  And the hypothesis profiles, chosen by ``HYPOTHESIS_PROFILE``."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings
from ros_probe import cold_environment

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config

# Hypothesis profiles.  "default" (``make test``): a bounded search, so that the
# property-based reader tests (tests/test_fuzz_*.py) add about a minute to the suite on a
# 2-core machine; "fuzz" (``make fuzz``): a long search of the same properties.  No
# deadline: the readers touch files, and this VM stalls its guests (the tests bound a hang
# themselves, tests/fuzz_support.py).  Tests with settings of their own keep them.
_PROFILE_COMMON = {"deadline": None, "print_blob": True,
                   "suppress_health_check": [HealthCheck.too_slow]}
settings.register_profile("default", max_examples=60, **_PROFILE_COMMON)
settings.register_profile("fuzz", max_examples=2500, **_PROFILE_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(scope="session")
def sport_cfg():
    return load_config()


@pytest.fixture(scope="session")
def sport_model(sport_cfg):
    return DamperModel(sport_cfg)


@pytest.fixture
def cli(capsys):
    """``damper-hil ARGS`` run by its ``main()`` in this process, as a
    ``CompletedProcess`` (exit status, stdout, stderr; argparse's ``SystemExit`` gives the
    status too).  For the bad-input checks: the same code path as the installed command
    without a new interpreter's 1.5 s start-up each (tests/test_errors.py runs the real
    process)."""
    from damper_hil.cli import main

    def run(*args: object) -> subprocess.CompletedProcess:
        argv = [str(a) for a in args]
        capsys.readouterr()
        try:
            rc = main(argv)
        except SystemExit as exc:  # argparse's usage errors
            rc = exc.code if isinstance(exc.code, int) else 1
        out = capsys.readouterr()
        return subprocess.CompletedProcess(["damper-hil", *argv], rc, out.out, out.err)
    return run


ROOT = Path(__file__).resolve().parents[1]
#: ROS domain of the shared demo run (away from every test module's own)
COLD_DEMO_DOMAIN = 141


@pytest.fixture(scope="session")
def cold_demo(tmp_path_factory):
    """``damper-hil demo --duration 5`` as a new user runs it, nothing cached (an empty
    ``NUMBA_CACHE_DIR``): the finished process and its ``--out`` folder.  One run serves
    the start-up and real-time checks (test_readiness) and the bag's contents
    (test_nodes): a demo takes 25–40 s of the suite's 15 minutes."""
    root = tmp_path_factory.mktemp("cold_demo")
    env = cold_environment(root, COLD_DEMO_DOMAIN)
    out = root / "demo"
    proc = subprocess.run([sys.executable, "-m", "damper_hil.cli", "demo", "--duration", "5",
                           "--out", str(out)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    return proc, out
