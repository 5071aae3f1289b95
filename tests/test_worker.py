"""The off-loop worker: a process of its own for the work a real-time loop hands off (the
identification's fit), polled without waiting, ended with its parent or its run."""

import os
import signal
import threading
import time

import numpy as np
import pytest

from damper_emulator.realtime.rt import RealtimeRequest, apply_realtime
from damper_emulator.realtime.worker import CLOSE_TIMEOUT_S, OffLoopWorker, WorkerError
from ride_sim.hybrid.params import CompensatorParams
from ride_sim.hybrid.rig_host import _fit_and_tracker, fit_worker
from ride_sim.hybrid.transfer import TransferEstimate, excitation, response


@pytest.fixture(scope="module")
def worker():
    with OffLoopWorker("test-worker") as w:
        yield w


def wait_done(job, timeout_s: float = 30.0) -> None:
    end = time.monotonic() + timeout_s
    while not job.done():
        assert time.monotonic() < end, "no result"
        time.sleep(0.001)


def test_a_result_comes_back_and_polling_never_waits(worker):
    job = worker.submit(time.sleep, 0.5)
    t0 = time.monotonic()
    polls = [job.done() for _ in range(100)]
    assert time.monotonic() - t0 < 0.1 and not any(polls)
    wait_done(job)
    assert job.result() is None
    assert worker.submit(divmod, 17, 5).result() == (3, 2)


def test_results_are_matched_to_their_jobs_whatever_the_order_they_are_read_in(worker):
    jobs = [worker.submit(pow, 2, k) for k in range(5)]
    assert [j.result() for j in reversed(jobs)] == [16, 8, 4, 2, 1]
    assert jobs[0].done() and jobs[0].result() == 1       # read again: the same


def test_the_tasks_own_exception_is_raised_in_the_caller(worker):
    job = worker.submit(int, "x")
    with pytest.raises(ValueError, match="invalid literal"):
        job.result()
    assert worker.submit(abs, -3).result() == 3           # the worker goes on


def test_the_worker_runs_under_the_normal_policy_when_a_fifo_thread_starts_it():
    seen: dict[str, object] = {}

    def fifo_thread() -> None:
        report = apply_realtime(RealtimeRequest(sched_fifo=True, priority=11,
                                                lock_memory=False))
        seen["fifo"] = report.sched_fifo
        with OffLoopWorker("test-fifo") as w:
            seen["worker"] = w.submit(os.sched_getscheduler, 0).result()
        seen["after"] = os.sched_getscheduler(0)

    t = threading.Thread(target=fifo_thread)
    t.start()
    t.join()
    if not seen["fifo"]:
        pytest.skip("SCHED_FIFO is not permitted here")
    assert seen["worker"] == os.SCHED_OTHER
    assert seen["after"] == os.SCHED_FIFO


def test_close_ends_a_running_task_at_once_and_its_job_says_so():
    w = OffLoopWorker("test-close")
    assert w.submit(int).result() == 0
    job = w.submit(time.sleep, 60)
    t0 = time.monotonic()
    w.close()
    assert time.monotonic() - t0 < CLOSE_TIMEOUT_S
    assert job.done()
    with pytest.raises(WorkerError, match="ended"):
        job.result()
    with pytest.raises(WorkerError, match="closed"):
        w.submit(int)
    w.close()                                             # idempotent


def test_a_worker_that_died_fails_its_job_and_the_next_submit():
    w = OffLoopWorker("test-died")
    pid = w.submit(os.getpid).result()
    job = w.submit(time.sleep, 60)
    os.kill(pid, signal.SIGKILL)
    # (waiting, the error gives the worker's status: a poll does not wait for it)
    with pytest.raises(WorkerError, match="status -9"):
        job.result()
    with pytest.raises(WorkerError, match="has ended"):
        w.submit(int)
    w.close()


def test_the_worker_ignores_sigint_its_parent_decides(worker):
    pid = worker.submit(os.getpid).result()
    os.kill(pid, signal.SIGINT)
    time.sleep(0.2)
    assert worker.submit(abs, -1).result() == 1


def test_the_worker_ends_when_its_parent_does(tmp_path):
    """A parent killed outright (no close) leaves no worker behind."""
    import subprocess
    import sys
    script = ("from damper_emulator.realtime.worker import OffLoopWorker\n"
              "import os, time\n"
              "if __name__ == '__main__':\n"
              "    w = OffLoopWorker('orphan')\n"
              "    print(w.submit(os.getpid).result(), flush=True)\n"
              "    time.sleep(60)\n")
    path = tmp_path / "parent.py"
    path.write_text(script)
    proc = subprocess.Popen([sys.executable, str(path)], stdout=subprocess.PIPE, text=True)
    pid = int(proc.stdout.readline())
    proc.kill()
    proc.wait()
    end = time.monotonic() + 10
    while time.monotonic() < end:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        with open(f"/proc/{pid}/stat") as f:            # a zombie of init's is gone too
            if f.read().split(") ", 1)[1].startswith("Z"):
                return
        time.sleep(0.05)
    pytest.fail(f"the worker {pid} outlived its parent")


def test_the_fit_worker_fits_as_the_loop_would_itself():
    """The identification's fit through the worker is the fit run in the caller: the same
    estimate, and a tracker that follows the same way."""
    dt = 1e-3
    p = CompensatorParams()
    truth = TransferEstimate(0.0071, 33.0, 0.6, 0.97)
    u = excitation(p.identify_s, dt, p.identify_amplitude_m, p.identify_band_hz, seed=3)
    x = response(u, dt, truth)
    usable = np.ones(u.size, dtype=bool)
    with fit_worker("test-fit") as w:
        estimate, tracker = w.submit(_fit_and_tracker, u, x, dt, p, usable).result()
    here, local = _fit_and_tracker(u, x, dt, p, usable)
    assert estimate == here
    assert estimate.delay_s == pytest.approx(truth.delay_s, abs=1e-5)
    assert estimate.bandwidth_hz == pytest.approx(truth.bandwidth_hz, rel=1e-3)
    for t in (tracker, local):           # the tracker came back as it was made
        t.start(0.0)
        for a, b in zip(10 * u, 10 * x):      # a ride's motion, not the test signal's
            t.push(float(a), float(b))
    assert tracker.updates == local.updates > 0
    assert (tracker.delay_s, tracker.gain) == (local.delay_s, local.gain)
