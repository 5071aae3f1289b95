"""Shared fixtures: the paper's 'sport' damper; one run of the demo; the command line
run in this process.  The hypothesis profiles, chosen by ``HYPOTHESIS_PROFILE``.  And the
order of the modules: the slow ones first."""

import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import load_config

# Hypothesis profiles.  "default" (``make test``): a bounded search, so that the
# property-based reader tests (tests/test_fuzz_*.py) add about a minute to the suite on a
# 2-core machine; "fuzz" (``make fuzz``): a long search of the same properties.  No
# deadline: the readers touch files, and a virtual machine's host can stall it (the tests
# bound a hang themselves, tests/fuzz_support.py).  Tests with settings of their own keep
# them.
_PROFILE_COMMON = {"deadline": None, "print_blob": True,
                   "suppress_health_check": [HealthCheck.too_slow]}
settings.register_profile("default", max_examples=60, **_PROFILE_COMMON)
settings.register_profile("fuzz", max_examples=2500, **_PROFILE_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


def pytest_collection_modifyitems(config, items):
    """The modules with a test marked ``slow`` first, each module's tests together and in
    their order.  ``make test``'s workers (``--dist loadscope --no-loadscope-reorder``)
    take whole modules in this order: the long ones start first, and the short ones fill
    in at the end.  (xdist's own order, by the number of tests, sent the diagnosis's few
    long tests last, and one worker ran them alone at the end.)"""
    def module(item: pytest.Item) -> str:
        return item.nodeid.split("::", 1)[0]

    slow = {module(item) for item in items if item.get_closest_marker("slow")}
    items.sort(key=lambda item: module(item) not in slow)


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
DEMO_DOMAIN = 141


@dataclass
class DemoRun:
    """One run of ``damper-hil demo --live``: the finished process, its ``--out`` folder,
    the live view's port, and what a WebSocket client received from the view meanwhile
    (``channels`` advertised, ``{topic: [payload, ...]}``; empty when the client failed,
    ``client_error`` says why)."""

    proc: subprocess.CompletedProcess
    out: Path
    port: int
    channels: list = field(default_factory=list)
    got: dict = field(default_factory=dict)
    client_error: str = ""


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory) -> DemoRun:
    """``damper-hil demo --duration 5 --live PORT --format mf4`` as ``make demo`` runs it
    for a new user: on the kernels the install's warm-up cached (a start with nothing
    cached is the emulator's, tests/test_readiness.py), with a live-view client listening.
    One run serves the start-up checks, the bag's contents and the live view
    (tests/test_demo_run.py, one module: one worker runs it once)."""
    import socket
    import threading

    from live_client import connect_when_up

    from damper_emulator.ros.launch import ros_environment

    root = tmp_path_factory.mktemp("demo")
    env = ros_environment(DEMO_DOMAIN)
    out = root / "demo"
    with socket.socket() as s:                      # a free port on this machine
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    run = DemoRun(subprocess.CompletedProcess([], -1), out, port)

    def listen() -> None:
        # until the view stops with the demo
        try:
            run.channels, run.got = connect_when_up(port, time.monotonic() + 300, 300.0)
        except Exception as exc:  # noqa: BLE001 - the test that needs it says why
            run.client_error = repr(exc)

    client = threading.Thread(target=listen, daemon=True)
    client.start()
    run.proc = subprocess.run([sys.executable, "-m", "damper_hil.cli", "demo", "--duration",
                               "5", "--live", str(port), "--format", "mf4", "--out",
                               str(out)], cwd=ROOT,
                              env=env, capture_output=True, text=True, timeout=600)
    client.join(30)
    return run


@pytest.fixture(scope="session")
def demo(demo_run):
    """The :func:`demo_run`'s finished process and ``--out`` folder."""
    return demo_run.proc, demo_run.out
