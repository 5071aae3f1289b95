"""Dyno plots: force–velocity and force–displacement loops, N-speed curves (PNG).

Figures are drawn with matplotlib's object interface on the Agg canvas (no pyplot, no
display, no global backend switch), so they render on headless machines and from threads.
Units on every axis: force kN, velocity m/s, displacement mm, time s.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import patheffects
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.text import Text
from matplotlib.ticker import FixedFormatter, FuncFormatter

from damper_emulator.errors import printable

DPI = 110
#: above this many samples loops are drawn with hair-lines
DENSE_SAMPLES = 5000
#: colour map of dense loops (by time)
DENSE_CMAP = "viridis"
_MODEL_STYLE = dict(color="black", linestyle="--", linewidth=1.3, zorder=5,
                    path_effects=[patheffects.withStroke(linewidth=3.0, foreground="white")])


def _arrays(data: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(time, displacement, velocity, force)`` of a :class:`MeasuredData`, a
    :class:`SimulationResult`, a mapping with those keys or a 4-tuple in that order."""
    if hasattr(data, "displacement"):  # MeasuredData
        v = data.velocity if data.velocity is not None else np.gradient(data.displacement,
                                                                         data.time)
        return data.time, data.displacement, v, data.force
    if hasattr(data, "stroke_m"):  # SimulationResult
        return data.time_s, data.stroke_m, data.velocity_m_s, data.force_n
    if isinstance(data, Mapping):
        t, x, f = data["time"], data["displacement"], data["force"]
        v = data.get("velocity")
        if v is None:
            v = np.gradient(x, t)
        return tuple(np.asarray(a, dtype=float) for a in (t, x, v, f))  # type: ignore
    t, x, v, f = data
    return tuple(np.asarray(a, dtype=float) for a in (t, x, v, f))  # type: ignore


def new_figure(width: float, height: float, layout: str | None = "constrained") -> Figure:
    """A figure on the Agg canvas (no pyplot), size in inches, constrained layout (or
    ``layout``: None for a figure that places its axes itself, at a third of the
    drawing's time)."""
    fig = Figure(figsize=(width, height), dpi=DPI, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _printable_labels(func: Any) -> Any:
    """A tick-label function whose labels are :func:`printable`."""
    if getattr(func, "printable", False):
        return func

    def label(x: Any, pos: Any = None) -> str:
        return printable(str(func(x, pos)))
    label.printable = True  # type: ignore[attr-defined]
    return label


def save(fig: Figure, path: str | Path, dpi: float = DPI) -> Path:
    """Write ``fig`` as PNG (at the project's resolution by default); returns the path.

    Every text of the figure is made printable first: a name that is not UTF-8 (a file
    or damper folder named in Latin-1, lone surrogates in Python) in a title, label or
    tick is drawn as ``\\xNN`` (:func:`~damper_emulator.errors.printable`); the font
    renderer refuses it otherwise.  Every plot of the project is saved here.
    """
    for text in fig.findobj(Text):
        shown = text.get_text()
        if isinstance(shown, str) and shown != printable(shown):
            text.set_text(printable(shown))
    for ax in fig.axes:
        # tick labels given as text (set_xticks(ticks, labels)) are drawn later, from the
        # axis's formatter: a FuncFormatter over the labels (a FixedFormatter before 3.8)
        for axis in (ax.xaxis, ax.yaxis):
            for formatter in (axis.get_major_formatter(), axis.get_minor_formatter()):
                if isinstance(formatter, FixedFormatter):
                    formatter.seq = [printable(str(label)) for label in formatter.seq]
                elif isinstance(formatter, FuncFormatter):
                    formatter.func = _printable_labels(formatter.func)
    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path


def _velocity_grid(v_lo: float, v_hi: float, n: int = 401) -> np.ndarray:
    """Velocities spanning ``[v_lo, v_hi]`` that include ±0 so the Coulomb step shows."""
    v_lo, v_hi = min(v_lo, 0.0), max(v_hi, 0.0)
    neg = np.linspace(v_lo, -1e-9, n // 2) if v_lo < 0 else np.empty(0)
    pos = np.linspace(1e-9, v_hi, n // 2) if v_hi > 0 else np.empty(0)
    return np.concatenate([neg, pos])


def _model_curve(ax, cfg, v_lo: float, v_hi: float, label: str | None = None) -> None:
    from damper_emulator.model.incompressible import incompressible_force

    vg = _velocity_grid(v_lo, v_hi)
    ax.plot(vg, incompressible_force(vg, cfg) / 1e3,
            label=label or f"incompressible model ({cfg.damper.name})", **_MODEL_STYLE)


def decorate(ax, xlabel: str, ylabel: str, legend: bool | str = True) -> None:
    """Axis labels, grid, zero lines and (optionally) a legend, the project's style;
    ``legend``: where (a matplotlib location), True for the best place (which searches the
    data: on long traces a tenth of a second per axes)."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.35)
    ax.locator_params(axis="x", nbins=7)
    xlim, ylim = ax.get_xlim(), ax.get_ylim()
    ax.axhline(0.0, color="0.5", linewidth=0.6)  # the axes, where they are in view
    ax.axvline(0.0, color="0.5", linewidth=0.6)
    ax.set_xlim(xlim)
    ax.set_ylim(ylim)
    if legend and ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best" if legend is True else legend, fontsize="small")


def _dense_loop(ax, xs: np.ndarray, ys: np.ndarray, t: np.ndarray, label: str):
    """A long trace drawn as hair-lines coloured by time (reads well at 60 000 points)."""
    pts = np.column_stack([xs, ys])
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(segs, array=0.5 * (t[1:] + t[:-1]), cmap=DENSE_CMAP,
                        linewidths=0.35, label=label)
    ax.add_collection(lc)
    ax.update_datalim(pts)
    ax.autoscale_view()
    return lc


def plot_loops(path: str | Path, data: Any, title: str, cfg=None,
               time_series: bool | None = None, label: str | None = None,
               velocity_points: bool = False) -> Path:
    """Force–velocity and force–displacement loops of one test, as a PNG.

    Parameters
    ----------
    path : output PNG
    data : MeasuredData, SimulationResult, mapping or ``(t, x, v, F)`` tuple (SI units)
    title : figure title
    cfg : ModelConfig, optional
        When given, the incompressible model (eqs 30–32) is overlaid dashed on the
        force–velocity panel over the data's velocity range.
    time_series : bool, optional
        Add displacement and force vs time panels on top (default: for more than
        :data:`DENSE_SAMPLES` samples, e.g. a chirp or a quasi-static test).
    label : legend entry of the data (default: a MeasuredData's file name, else
        "simulated dyno")
    velocity_points : bool
        Draw the force–velocity panel as points, not lines (for a quasi-static test, whose
        velocity only takes two values: lines would draw the reversals as fake slopes).

    Traces longer than :data:`DENSE_SAMPLES` samples are drawn as hair-lines coloured by
    time, with a colour bar.
    """
    t, x, v, f = _arrays(data)
    if label is None:
        label = getattr(data, "name", "") or "simulated dyno"
    n = t.size
    dense = n > DENSE_SAMPLES
    if time_series is None:
        time_series = dense
    if time_series:
        fig = new_figure(11.0, 9.0)
        gs = fig.add_gridspec(3, 2, height_ratios=[0.55, 0.7, 1.6])
        ax_x = fig.add_subplot(gs[0, :])
        ax_t = fig.add_subplot(gs[1, :], sharex=ax_x)
        ax_fv, ax_fx = fig.add_subplot(gs[2, 0]), fig.add_subplot(gs[2, 1])
        thin = dict(linewidth=0.4 if dense else 1.0)
        ax_x.plot(t, x * 1e3, color="C1", **thin)
        ax_x.set_ylabel("displacement [mm]")
        ax_x.tick_params(labelbottom=False)
        ax_t.plot(t, f / 1e3, color="C0", **thin)
        ax_t.set_ylabel("force [kN]")
        ax_t.set_xlabel("time [s]")
        ax_x.set_xlim(t[0], t[-1])
        for ax in (ax_x, ax_t):
            ax.grid(True, alpha=0.35)
    else:
        fig = new_figure(11.0, 4.8)
        ax_fv, ax_fx = fig.subplots(1, 2)
    if dense:
        if velocity_points:
            ax_fv.scatter(v, f / 1e3, c=t, cmap=DENSE_CMAP, s=2.0, linewidths=0,
                          label=label)
        else:
            _dense_loop(ax_fv, v, f / 1e3, t, label)
        lc = _dense_loop(ax_fx, x * 1e3, f / 1e3, t, label)
        fig.colorbar(lc, ax=[ax_fv, ax_fx], label="time [s]", shrink=0.9, pad=0.01)
    else:
        if velocity_points:
            ax_fv.plot(v, f / 1e3, ".", color="C0", markersize=3, label=label)
        else:
            ax_fv.plot(v, f / 1e3, color="C0", label=label, linewidth=1.3)
        ax_fx.plot(x * 1e3, f / 1e3, color="C0", label=label, linewidth=1.3)
    if cfg is not None:
        _model_curve(ax_fv, cfg, float(v.min()), float(v.max()))
    decorate(ax_fv, "velocity [m/s] (extension +)", "force [kN] (rebound +)")
    ax_fv.set_title("force–velocity")
    decorate(ax_fx, "displacement [mm] (extension +)", "force [kN] (rebound +)")
    ax_fx.set_title("force–displacement")
    fig.suptitle(title, wrap=True)
    return save(fig, path)


def plot_sines_overlay(path: str | Path,
                       sines: Iterable[Sequence[Any]],
                       title: str = "Validation sines: force–velocity and force–displacement",
                       cfg=None) -> Path:
    """Several sine tests on the same two panels (F–v, F–x) so that the growth of the
    hysteresis with frequency is visible.

    ``sines`` holds ``(label, displacement [m], velocity [m/s], force [N])`` tuples.
    """
    sines = list(sines)
    fig = new_figure(11.5, 5.0)
    ax_fv, ax_fx = fig.subplots(1, 2)
    v_lo = v_hi = 0.0
    for k, (label, x, v, f) in enumerate(sines):
        x, v, f = (np.asarray(a, dtype=float) for a in (x, v, f))
        ax_fv.plot(v, f / 1e3, color=f"C{k}", linewidth=1.3, label=label)
        ax_fx.plot(x * 1e3, f / 1e3, color=f"C{k}", linewidth=1.3, label=label)
        v_lo, v_hi = min(v_lo, float(v.min())), max(v_hi, float(v.max()))
    if cfg is not None and sines:
        _model_curve(ax_fv, cfg, v_lo, v_hi, label="incompressible model (no hysteresis)")
    decorate(ax_fv, "velocity [m/s] (extension +)", "force [kN] (rebound +)")
    ax_fv.set_title("force–velocity")
    # one legend (left) serves both panels: the colours are shared
    decorate(ax_fx, "displacement [mm] (extension +)", "force [kN] (rebound +)",
              legend=False)
    ax_fx.set_title("force–displacement")
    fig.suptitle(title, wrap=True)
    return save(fig, path)


def plot_fourteen_speed(path: str | Path, table: Mapping[str, Any], cfg=None,
                        title: str | None = None) -> Path:
    """Peak force vs peak velocity of an N-speed test, rebound and compression.

    ``table`` maps the columns of ``14speed.csv`` (``peak_velocity_rebound_m_s``,
    ``peak_force_rebound_n``, ``peak_velocity_compression_m_s``,
    ``peak_force_compression_n``; SI units) to arrays.  With ``cfg`` the incompressible
    model curve is overlaid dashed.
    """
    vr = np.asarray(table["peak_velocity_rebound_m_s"], dtype=float)
    fr = np.asarray(table["peak_force_rebound_n"], dtype=float)
    vc = np.asarray(table["peak_velocity_compression_m_s"], dtype=float)
    fc = np.asarray(table["peak_force_compression_n"], dtype=float)
    fig = new_figure(8.0, 5.6)
    ax = fig.subplots()
    ax.plot(vr, fr / 1e3, "o-", color="C1", markersize=5, linewidth=1.2,
            label="rebound: max force vs max velocity")
    ax.plot(vc, fc / 1e3, "s-", color="C0", markersize=5, linewidth=1.2,
            label="compression: min force vs min velocity")
    if cfg is not None:
        _model_curve(ax, cfg, float(vc.min()), float(vr.max()))
    decorate(ax, "peak velocity [m/s] (extension +)", "peak force [kN] (rebound +)")
    ax.set_title(title or f"{vr.size}-speed test: peak force vs peak velocity")
    return save(fig, path)
