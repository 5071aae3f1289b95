"""Figures of a validation (``damper-hil validate --report``): measured and simulated
loops overlaid per file, and the r.m.s. error per file.  The report side of
:mod:`damper_emulator.validation`, which computes what they show."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.dyno.plots import DENSE_SAMPLES, decorate, new_figure, save
from damper_emulator.validation import SERIES_KEY


def rms_caption(result: Mapping[str, Any]) -> str:
    rel = result.get("relative_rms")
    rel_txt = f" ({100.0 * rel:.2f} % of r.m.s. force)" if rel is not None else ""
    return f"r.m.s. error {result['rms_N']:.3g} N{rel_txt}"


def _piecewise_constant(v: np.ndarray) -> bool:
    """True when the velocity mostly sits on ± one value (a constant-velocity triangle)."""
    a = np.abs(v)
    ref = float(np.median(a))
    return ref > 0 and float(np.mean(np.abs(a - ref) <= 0.01 * ref)) > 0.8


def plot_validation(path: str | Path, result: Mapping[str, Any],
                    title: str | None = None) -> Path:
    """Measured and simulated force–velocity and force–displacement loops overlaid, and
    the force error against time, as a PNG.  The title carries the r.m.s. error."""
    s = result[SERIES_KEY]
    t, x, v = s["time"], s["displacement"], s["velocity"]
    fm, fs = s["force_measured"], s["force_simulated"]
    dense = t.size > DENSE_SAMPLES
    lw_m, lw_s = (0.3, 0.3) if dense else (1.6, 1.1)
    fig = new_figure(11.0, 7.4)
    gs = fig.add_gridspec(2, 2, height_ratios=[1.6, 0.75])
    ax_fv, ax_fx = fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 1])
    ax_e = fig.add_subplot(gs[1, :])
    meas = dict(color="C0", linewidth=lw_m, label="measured")
    sim = dict(color="C3", linewidth=lw_s, alpha=0.85, label="simulated (compressible model)")
    if not dense:
        sim["linestyle"] = "--"
    if _piecewise_constant(v):
        # a quasi-static test: lines would draw the velocity reversals as fake slopes
        ax_fv.plot(v, fm / 1e3, ".", color="C0", markersize=3, label="measured")
        ax_fv.plot(v, fs / 1e3, ".", color="C3", markersize=2, alpha=0.85,
                   label="simulated (compressible model)")
    else:
        ax_fv.plot(v, fm / 1e3, **meas)
        ax_fv.plot(v, fs / 1e3, **sim)
    ax_fx.plot(x * 1e3, fm / 1e3, **meas)
    ax_fx.plot(x * 1e3, fs / 1e3, **sim)
    decorate(ax_fv, "velocity [m/s] (extension +)", "force [kN] (rebound +)")
    legend = ax_fv.get_legend()
    if legend is not None:  # hair-lines and small dots are invisible in the legend
        for handle in legend.legend_handles:
            if hasattr(handle, "set_linewidth"):
                handle.set_linewidth(2.0)
            if hasattr(handle, "set_markersize"):
                handle.set_markersize(6.0)
    ax_fv.set_title("force–velocity")
    decorate(ax_fx, "displacement [mm] (extension +)", "force [kN] (rebound +)",
              legend=False)
    ax_fx.set_title("force–displacement")
    ax_e.plot(t, fs - fm, color="C2", linewidth=0.4 if dense else 0.9)
    ax_e.axhline(0.0, color="0.5", linewidth=0.6)
    ax_e.set_xlim(t[0], t[-1])
    ax_e.set_xlabel("time [s]")
    ax_e.set_ylabel("F_sim − F_meas [N]")
    ax_e.grid(True, alpha=0.35)
    name = result.get("name") or "data"
    fig.suptitle(title or f"{name}: {rms_caption(result)}", wrap=True)
    return save(fig, path)


def plot_relative_rms_summary(path: str | Path, results: Mapping[str, Mapping[str, Any]],
                              title: str | None = None) -> Path:
    """Bar plot of the relative r.m.s. error [%] per file, each bar labelled with the
    r.m.s. error in newtons."""
    names = list(results)
    rel = [100.0 * (results[n].get("relative_rms") or 0.0) for n in names]
    fig = new_figure(max(6.0, 1.1 * len(names) + 3.0), 4.8)
    ax = fig.subplots()
    bars = ax.bar(range(len(names)), rel, color="C0")
    ax.bar_label(bars, labels=[f"{results[n]['rms_N']:.3g} N" for n in names],
                 padding=2, fontsize="small")
    ax.set_xticks(range(len(names)), names, rotation=20 if len(names) > 4 else 0,
                  ha="right" if len(names) > 4 else "center")
    ax.set_ylabel("relative r.m.s. force error [%]")
    ax.set_ylim(0.0, max([*rel, 0.001]) * 1.18)
    ax.grid(True, axis="y", alpha=0.35)
    ax.set_title(title or "Validation: r.m.s. force error per file (label: newtons)")
    return save(fig, path)
