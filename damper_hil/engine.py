"""Dask, the engine of the project's distributed work (``fleet``, ``tune``).

One interface, :func:`open_engine`, over three ways of running independent tasks:

* ``scheduler="tcp://host:port"``: any running Dask cluster (``dask scheduler`` plus
  ``dask worker`` processes, a Kubernetes or HPC cluster, ...), reached with a
  :class:`distributed.Client`;
* ``workers=N`` (N > 1, the default when neither is given: the CPU count): a
  :class:`distributed.LocalCluster` of N single-threaded worker processes started for the
  run, every server of it (scheduler, workers, nannies, their HTTP endpoints) bound to
  127.0.0.1 on a free port;
* ``workers=1``: dask's synchronous scheduler in this process (no cluster, nothing to
  start; what a debugger or a profiler wants).

:meth:`Engine.map_unordered` yields each task's :class:`Outcome` as soon as it is done, so
that the caller writes every result the moment it exists (a killed run loses only the
tasks in flight).  At most ``window`` tasks are submitted ahead of the results: their
arguments (the data they ship) are held by the scheduler until they finish.  A worker lost
in the middle of a task costs only that task: the scheduler runs it again elsewhere, up
to ``distributed.scheduler.allowed-failures`` times (dask's default: 3); after that the
task's outcome is the error ``KilledWorker``.

A task's own exception comes back in its :class:`Outcome`; it never stops the others.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from damper_emulator.errors import UserError, one_line

#: how long to wait for a scheduler given by --scheduler before giving up [s]
CONNECT_TIMEOUT_S = 15.0
#: tasks submitted ahead of the results, per worker
WINDOW_PER_WORKER = 2
#: the interface every local cluster binds to: no traffic leaves this machine
LOCALHOST = "127.0.0.1"

K = TypeVar("K")
T = TypeVar("T")


class EngineError(UserError):
    """The engine cannot be used: no scheduler at the address, a bad worker count, or the
    scheduler lost in the middle of a run (one line)."""


@dataclass(frozen=True)
class Outcome(Generic[K]):
    """What one task came to: ``value`` when it returned, else ``error`` (its exception,
    or the engine's: ``KilledWorker`` when its workers kept dying)."""

    key: K
    value: Any = None
    error: BaseException | None = None


def default_workers() -> int:
    """The CPU count (at least 1)."""
    return max(1, os.cpu_count() or 1)


class Engine:
    """Runs independent tasks; see :func:`open_engine`."""

    #: one line saying where the tasks run
    description: str = ""
    #: how many tasks can run at once
    workers: int = 1

    def map_unordered(self, fn: Callable[[T], Any], items: Iterable[tuple[K, T]],
                      window: int | None = None) -> Iterator[Outcome[K]]:
        """``fn(arg)`` for every ``(key, arg)`` of ``items``, yielded as they finish."""
        raise NotImplementedError


class SynchronousEngine(Engine):
    """Dask's synchronous scheduler: every task in this process, one after the other."""

    def __init__(self) -> None:
        self.description = "dask synchronous scheduler (this process, 1 worker)"
        self.workers = 1

    def map_unordered(self, fn: Callable[[T], Any], items: Iterable[tuple[K, T]],
                      window: int | None = None) -> Iterator[Outcome[K]]:
        import dask

        for key, arg in items:
            try:
                value = dask.delayed(fn, pure=False)(arg).compute(scheduler="synchronous")
            except Exception as exc:  # noqa: BLE001 - the task's failure is its outcome
                yield Outcome(key, error=exc)
            else:
                yield Outcome(key, value=value)


class DaskEngine(Engine):
    """A :class:`distributed.Client` on a cluster (local or remote)."""

    def __init__(self, client: Any, description: str) -> None:
        self.client = client
        self.description = description
        self.workers = max(1, self._current_workers())

    def map_unordered(self, fn: Callable[[T], Any], items: Iterable[tuple[K, T]],
                      window: int | None = None) -> Iterator[Outcome[K]]:
        from distributed import as_completed

        limit = max(1, window or WINDOW_PER_WORKER * self.workers)
        pending = iter(items)
        keys: dict[Any, K] = {}
        running = as_completed()

        def submit_next() -> bool:
            for key, arg in pending:
                future = self.client.submit(fn, arg, pure=False)
                keys[future.key] = key
                running.add(future)
                return True
            return False

        def fill() -> None:
            while len(keys) < limit and submit_next():
                pass

        fill()
        for future in running:
            limit = max(limit, WINDOW_PER_WORKER * self._current_workers())
            key = keys.pop(future.key)
            try:
                value = future.result()
            except Exception as exc:  # noqa: BLE001 - a task's failure (or KilledWorker) is its outcome
                outcome: Outcome[K] = Outcome(key, error=exc)
            else:
                outcome = Outcome(key, value=value)
            future.release()
            if self.client.status not in ("running", "connecting"):
                raise EngineError(f"lost the Dask scheduler ({self.description}); the "
                                  "finished tasks are kept")
            fill()
            yield outcome

    def _current_workers(self) -> int:
        """Worker threads now (a remote cluster's workers may come and go)."""
        return sum(w.get("nthreads", 1) for w in
                   self.client.scheduler_info()["workers"].values())


@contextlib.contextmanager
def open_engine(scheduler: str | None = None, workers: int | None = None,
                connect_timeout_s: float = CONNECT_TIMEOUT_S) -> Iterator[Engine]:
    """The engine for ``--scheduler ADDRESS`` or ``--workers N`` (module docstring).

    Raises
    ------
    EngineError
        Both given, a worker count below 1, or no scheduler answering at ``scheduler``
        within ``connect_timeout_s``.
    """
    if scheduler is not None and workers is not None:
        raise EngineError("give --scheduler or --workers, not both (the cluster at "
                          "--scheduler has its own workers)")
    if scheduler is None:
        n = default_workers() if workers is None else workers
        if n < 1:
            raise EngineError(f"--workers must be at least 1, got {n}")
        if n == 1:
            yield SynchronousEngine()
            return
        from distributed import Client, LocalCluster

        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                          host=LOCALHOST, scheduler_port=0,
                          # their HTTP servers (health, metrics) too, on free ports
                          dashboard_address=f"{LOCALHOST}:0",
                          worker_dashboard_address=f"{LOCALHOST}:0",
                          silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            yield DaskEngine(client, f"local Dask cluster, {n} worker processes "
                                     f"({cluster.scheduler_address})")
        return
    from distributed import Client

    try:
        client = Client(scheduler, timeout=f"{connect_timeout_s:g}s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise EngineError(f"cannot reach the Dask scheduler at {scheduler!r} within "
                          f"{connect_timeout_s:g} s ({one_line(exc, with_type=True)})"
                          ) from None
    with client:
        info = client.scheduler_info()["workers"]
        yield DaskEngine(client, f"Dask scheduler {scheduler} ({len(info)} workers)")


# --------------------------------------------------------------------------------------
# A cluster of separate processes, as on a real deployment: what the tests and the
# benchmark start to exercise --scheduler (and the recipe for a user's own machines).


def scheduler_command(scheduler_file: Path) -> list[str]:
    """``dask scheduler`` on 127.0.0.1 (a free port; its address in ``scheduler_file``)."""
    return [str(_dask_cli()), "scheduler", "--host", LOCALHOST, "--port", "0",
            "--no-dashboard", "--dashboard-address", f"{LOCALHOST}:0",
            "--scheduler-file", str(scheduler_file)]


def worker_command(address: str, name: str) -> list[str]:
    """One single-threaded ``dask worker`` (with its nanny) on 127.0.0.1."""
    return [str(_dask_cli()), "worker", address, "--host", LOCALHOST, "--nthreads", "1",
            "--no-dashboard", "--dashboard-address", f"{LOCALHOST}:0", "--name", name]


def _dask_cli() -> Path:
    return Path(sys.executable).with_name("dask")


@dataclass
class CommandCluster:
    """A running ``dask scheduler`` and ``dask worker`` processes (each in its own process
    group, so that :meth:`kill` takes a worker's nanny and worker process together)."""

    address: str
    scheduler: subprocess.Popen[bytes]
    workers: list[subprocess.Popen[bytes]]

    def kill(self, proc: subprocess.Popen[bytes]) -> None:
        """SIGKILL to ``proc``'s process group; waits for it."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)


@contextlib.contextmanager
def command_cluster(workdir: Path, workers: int, start_timeout_s: float = 120.0
                    ) -> Iterator[CommandCluster]:
    """Start :func:`scheduler_command` and ``workers`` × :func:`worker_command` (logs in
    ``workdir``), wait until every worker has joined, and kill them all at the end."""
    sched_file = workdir / "scheduler.json"

    def start(cmd: list[str], log: str) -> subprocess.Popen[bytes]:
        with (workdir / log).open("wb") as fh:
            return subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT,
                                    start_new_session=True)

    sched = start(scheduler_command(sched_file), "scheduler.log")
    procs: list[subprocess.Popen[bytes]] = []
    cluster = CommandCluster("", sched, procs)
    try:
        deadline = time.monotonic() + start_timeout_s
        while not sched_file.exists():
            if sched.poll() is not None or time.monotonic() > deadline:
                raise EngineError(f"dask scheduler did not start (log: "
                                  f"{workdir / 'scheduler.log'})")
            time.sleep(0.1)
        cluster.address = json.loads(sched_file.read_text())["address"]
        procs += [start(worker_command(cluster.address, f"w{k}"), f"worker{k}.log")
                  for k in range(workers)]
        from distributed import Client

        with Client(cluster.address, timeout=f"{start_timeout_s:g}s") as client:
            client.wait_for_workers(workers, timeout=start_timeout_s)
        yield cluster
    finally:
        for p in (*procs, sched):
            cluster.kill(p)
