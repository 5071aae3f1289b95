"""The replay's figure (``replay.png``): recorded and replayed force, their difference,
and a detail around the largest.  A module of its own, light to import (numpy; matplotlib
only when drawing), for the process that draws it
(:class:`~damper_emulator.plot_process.PlotProcess`, started by
:func:`damper_emulator.replay.run_replay` before the replay's work)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: what the drawing process imports before the figure's data arrive (matplotlib's import
#: is most of the drawing's time)
PRELOAD = ("damper_emulator.dyno.plots",)


@dataclass(frozen=True)
class ReplayTraces:
    """What :func:`plot_replay` draws, as plain arrays (sent to the process that draws
    it, :class:`~damper_emulator.plot_process.PlotProcess`); times from the first stamp
    [s], forces [N]."""

    t_rec: np.ndarray          # the recorded forces' stamps
    f_rec: np.ndarray          # the recorded forces
    t_rep: np.ndarray          # the replayed outputs' stamps
    f_rep: np.ndarray          # the replayed outputs
    fault: np.ndarray          # the replayed outputs that are fault outputs (indices)
    compared: np.ndarray       # the outputs compared (indices, Comparison.index)
    difference_n: np.ndarray   # replayed − recorded there
    label: str                 # the difference's legend: its r.m.s. and max
    recorded: str = "/damper/force"   # what the recorded forces are


def plot_replay(path: str | os.PathLike[str], traces: ReplayTraces, title: str,
                zoom_s: float = 0.25) -> Path:
    """Recorded and replayed force against time, their difference, and a ``zoom_s`` detail
    around the largest difference (PNG; :func:`replay_traces`).  The axes are placed, and
    the legends put in their corners, by hand: a replay is a command users wait for, and
    matplotlib's constrained layout and best-place legends would double the drawing's
    time."""
    from damper_emulator.dyno.plots import decorate, new_figure, save

    fig = new_figure(11.0, 9.5, layout=None)
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.06, top=0.95, hspace=0.42)
    ax, ax_d, ax_z = fig.subplots(3, 1, height_ratios=(3, 2, 2.4))
    ax_d.sharex(ax)
    t_rec, f_rec, t_rep, fault = traces.t_rec, traces.f_rec, traces.t_rep, traces.fault

    def overlay(a, faults: np.ndarray) -> None:
        a.plot(t_rec, f_rec * 1e-3, color="tab:blue", linewidth=2.2, alpha=0.45,
               label=f"recorded {traces.recorded}")
        a.plot(t_rep, traces.f_rep * 1e-3, color="black", linewidth=0.7,
               label="replayed (model and fault outputs)")
        if faults.size:
            a.plot(t_rep[faults], traces.f_rep[faults] * 1e-3, linestyle="none", marker="|",
                   color="tab:red", markersize=8, label=f"fault outputs ({faults.size})")

    overlay(ax, fault)
    decorate(ax, "", "force [kN, rebound +]", legend="upper right")
    ax.set_title(title, fontsize="medium")
    if traces.compared.size:
        ax_d.plot(t_rep[traces.compared], traces.difference_n, color="tab:purple",
                  linewidth=0.7, label=traces.label)
        worst = traces.compared[int(np.argmax(np.abs(traces.difference_n)))]
        centre = float(t_rep[worst])
    else:
        centre = float(t_rep[0]) if t_rep.size else 0.0
    decorate(ax_d, "time [s] (from the first stamp)", "replayed − recorded [N]",
             legend="upper right")
    first = float(min(t_rec.min(), t_rep.min() if t_rep.size else t_rec.min()))
    last = float(max(t_rec.max(), t_rep.max() if t_rep.size else t_rec.max()))
    lo = min(max(centre - zoom_s / 2, first), max(last - zoom_s, first))
    hi = lo + zoom_s
    overlay(ax_z, fault[(t_rep[fault] >= lo) & (t_rep[fault] <= hi)])
    inside = (t_rec >= lo) & (t_rec <= hi)
    ax_z.plot(t_rec[inside], f_rec[inside] * 1e-3, linestyle="none", marker=".",
              markersize=3, color="tab:blue", label="recorded samples")
    ax_z.set_xlim(lo, hi)
    near = np.concatenate([f_rec[inside], traces.f_rep[(t_rep >= lo) & (t_rep <= hi)]])
    if near.size:
        pad = 0.08 * max(float(np.ptp(near)), 1.0)
        ax_z.set_ylim((near.min() - pad) * 1e-3, (near.max() + pad) * 1e-3)
    ax_z.set_title(f"detail: {zoom_s * 1e3:g} ms around the largest difference",
                   fontsize="small")
    decorate(ax_z, "time [s] (from the first stamp)", "force [kN, rebound +]",
             legend="upper right")
    return save(fig, path)
