"""Start and stop the project's nodes as separate processes (there is no ``ros2 launch`` in
the PyPI wheels): used by ``damper-hil demo``, the benchmarks and the tests.

Every process gets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and the caller's
``ROS_DOMAIN_ID``, so no traffic leaves the machine.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import yaml

#: How long a stopped node has for a clean shutdown before SIGKILL [s]: longer than a
#: publisher's wait for its subscribers' acknowledgements
#: (:data:`damper_emulator.topics.ACK_TIMEOUT_S`).
STOP_TIMEOUT_S = 30.0
#: Default domain range for runs that were not given one: 40 .. 89 by process id.
_DOMAIN_BASE, _DOMAIN_SPAN = 40, 50


def ros_environment(domain_id: int | None = None,
                    base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (default ``os.environ``) with localhost-only discovery and a domain id:
    ``domain_id``, else ``$ROS_DOMAIN_ID``, else one derived from the process id."""
    env = dict(os.environ if base is None else base)
    if domain_id is None:
        domain_id = int(env.get("ROS_DOMAIN_ID") or
                        _DOMAIN_BASE + os.getpid() % _DOMAIN_SPAN)
    env["ROS_DOMAIN_ID"] = str(int(domain_id))
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


def node_command(subcommand: str, params: Mapping[str, object] | None = None,
                 params_files: Sequence[str | Path] = (),
                 extra: Sequence[str] = ()) -> list[str]:
    """``python -m damper_hil.cli SUBCOMMAND [extra] --ros-args --params-file F -p
    name:=value ...`` (values written as ROS 2 YAML scalars)."""
    cmd = [sys.executable, "-m", "damper_hil.cli", subcommand, *extra]
    ros: list[str] = []
    for f in params_files:
        ros += ["--params-file", str(f)]
    for name, value in (params or {}).items():
        ros += ["-p", f"{name}:={_yaml_scalar(value)}"]
    if ros:
        cmd += ["--ros-args", *ros]
    return cmd


def _yaml_scalar(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        text = repr(value)
        return text if any(c in text for c in ".en") else text + ".0"
    if isinstance(value, str):
        try:
            plain = yaml.safe_load(value) == value
        except yaml.YAMLError:
            plain = False
        return value if plain and value else "'" + value.replace("'", "''") + "'"
    return str(value)


class NodeProcess:
    """One node in its own process, output to a log file.  Start it under
    :func:`~damper_emulator.signals.signals_held`, together with the statement that keeps
    it, where a signal's handler is to stop it: a Ctrl-C or a kill between the two would
    leave a started node that nobody stops.

    Parameters
    ----------
    name : str
        Label (and log file stem).
    command : list of str
        From :func:`node_command`.
    env : mapping
        From :func:`ros_environment`.
    log_dir : path
        ``<log_dir>/<name>.log`` receives stdout and stderr.
    """

    def __init__(self, name: str, command: Sequence[str], env: Mapping[str, str],
                 log_dir: str | Path):
        self.name = name
        self.log_path = Path(log_dir) / f"{name}.log"
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = self.log_path.open("wb")
        #: when it was launched [s, ``time.monotonic``]
        self.started = time.monotonic()
        self.proc = subprocess.Popen(list(command), env=dict(env), stdout=self._log,
                                     stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def poll(self) -> int | None:
        return self.proc.poll()

    def wait(self, timeout_s: float | None = None) -> int:
        return self.proc.wait(timeout_s)

    def stop(self, timeout_s: float = STOP_TIMEOUT_S) -> int:
        """SIGINT (a clean shutdown: the node closes its files and waits for its subscribers
        to have what it published), then SIGKILL after ``timeout_s``.  Returns the exit
        status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode

    def kill(self) -> None:
        """SIGKILL, no clean-up (the crash case)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._log.close()

    def log_tail(self, lines: int = 5) -> str:
        try:
            text = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return ""
        return "\n".join(text[-lines:])

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
