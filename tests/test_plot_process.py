"""``damper_emulator.plot_process``: a figure drawn in a process of its own, its result or
its exception back in the caller, nothing left running."""

from __future__ import annotations

import os

import numpy as np
import pytest

from damper_emulator.plot_process import PlotProcess, PlotProcessError
from damper_emulator.replay_figure import PRELOAD, ReplayTraces


def traces(n: int = 2000) -> ReplayTraces:
    t = np.linspace(0.0, 2.0, n)
    f = 1e3 * np.sin(2 * np.pi * t)
    rep = f + np.where(t > 1.5, 5.0, 0.0)
    return ReplayTraces(t, f, t, rep, np.array([10, 11]), np.arange(n), rep - f,
                        "r.m.s. 2.5 N")


def test_the_figure_is_drawn_in_the_child_and_its_path_comes_back(tmp_path):
    with PlotProcess("damper_emulator.replay_figure", "plot_replay", PRELOAD) as painter:
        path = painter.call(tmp_path / "replay.png", traces(), "a title")
    assert path == tmp_path / "replay.png"
    assert path.read_bytes()[:4] == b"\x89PNG" and path.stat().st_size > 10_000


def test_an_exception_of_the_child_is_raised_in_the_caller(tmp_path):
    """An unwritable figure is the caller's OSError, as in one process."""
    missing = tmp_path / "no such folder" / "replay.png"
    with PlotProcess("damper_emulator.replay_figure", "plot_replay") as painter, \
            pytest.raises(FileNotFoundError):
        painter.call(missing, traces(), "a title")


def test_a_child_that_dies_is_an_error_of_the_environment_not_silence():
    painter = PlotProcess("damper_emulator.replay_figure", "plot_replay")
    os.kill(painter._proc.pid, 9)
    with pytest.raises(PlotProcessError, match="without an answer"):
        painter.call("x.png", traces(), "a title")
    with pytest.raises(PlotProcessError, match="already used"):
        painter.call("x.png", traces(), "a title")


def test_closed_before_a_call_the_child_is_gone():
    painter = PlotProcess("damper_emulator.replay_figure", "plot_replay", PRELOAD)
    proc = painter._proc
    painter.close()
    assert proc.poll() is not None
    painter.close()   # twice is harmless
