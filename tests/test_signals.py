"""``damper_emulator.signals.signals_held``: a node started as a kill lands is still
stopped (the demo's nodes, the loopback's)."""

from __future__ import annotations

import os
import signal
import threading

import pytest

from damper_emulator.signals import signals_held


class Killed(BaseException):
    """What the test's SIGTERM handler raises (as the command line's does)."""


@pytest.fixture
def raising_sigterm():
    def handler(signum, frame):
        raise Killed(signum)

    previous = signal.signal(signal.SIGTERM, handler)
    yield handler
    signal.signal(signal.SIGTERM, previous)


def kill_self_and_go_on(done: list[str]) -> None:
    """SIGTERM to this process, then bytecode where its handler runs unless held."""
    os.kill(os.getpid(), signal.SIGTERM)
    for _ in range(1000):
        pass
    done.append("went on")


def held_kill(done: list[str]) -> None:
    with signals_held():
        kill_self_and_go_on(done)
        done.append("kept")


def test_a_kill_inside_is_raised_after_the_body_has_run(raising_sigterm):
    done: list[str] = []
    with pytest.raises(Killed):
        held_kill(done)
    assert done == ["went on", "kept"]
    assert signal.getsignal(signal.SIGTERM) is raising_sigterm


def test_two_signals_inside_both_reach_their_handlers():
    seen = []
    previous = signal.signal(signal.SIGINT, lambda s, f: seen.append(s))
    try:
        with signals_held():
            os.kill(os.getpid(), signal.SIGINT)
            os.kill(os.getpid(), signal.SIGINT)
            assert seen == []
        assert seen == [signal.SIGINT, signal.SIGINT]
    finally:
        signal.signal(signal.SIGINT, previous)


def test_without_a_signal_nothing_changes(raising_sigterm):
    with signals_held():
        value = 1
    assert value == 1
    assert signal.getsignal(signal.SIGTERM) is raising_sigterm
    done: list[str] = []
    with pytest.raises(Killed):
        kill_self_and_go_on(done)
    assert done == []


def test_outside_the_main_thread_it_holds_nothing(raising_sigterm):
    """Python runs handlers in the main thread only, and sets them only there."""
    errors = []

    def body():
        try:
            with signals_held():
                pass
        except BaseException as exc:  # noqa: BLE001 - the test reports any
            errors.append(exc)

    t = threading.Thread(target=body)
    t.start()
    t.join()
    assert errors == []
    assert signal.getsignal(signal.SIGTERM) is raising_sigterm
