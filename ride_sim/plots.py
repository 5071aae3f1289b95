"""Figures of the ride studies (:mod:`ride_sim.study`), PNG on the Agg canvas.

Drawn with the project's plot helpers (:func:`damper_emulator.dyno.plots.new_figure`,
``save``, ``decorate``) at a modest resolution for the docs.  Units: SWS mm, acceleration
m/s², DTL kN, time s, frequency Hz.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal as sps

from damper_emulator.dyno.plots import decorate, new_figure, save
from ride_sim.frequency_domain import transfer_functions
from ride_sim.iso2631 import frequency_weighting, weight_signal
from ride_sim.study import StudyResult
from ride_sim.study_linear import band_sensitivity
from ride_sim.study_paper import LABELS, PAPER_FIGURE_10
from ride_sim.study_setup import StudySettings, band_at_speed

#: Resolution of the study figures [dpi] (modest PNGs for the docs).
DPI = 100
COLOURS = {"linear": "C0", "14speed": "C1", "nonlinear": "C3", "incompressible": "C2",
           "linear_exact": "k"}
STYLES = {"incompressible": ":", "linear_exact": "--"}


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save(fig, path, dpi=DPI)


def _line(kind: str) -> dict[str, Any]:
    return dict(color=COLOURS.get(kind, "0.4"), linestyle=STYLES.get(kind, "-"),
                linewidth=1.0 if kind != "incompressible" else 1.2,
                label=LABELS.get(kind, kind))


def _log_grid(ax) -> None:
    ax.grid(True, which="major", alpha=0.35)
    ax.grid(True, which="minor", alpha=0.12)


# --------------------------------------------------------------------------------------
# figure 10


def plot_sws_history(path: str | Path, result: StudyResult, seconds: float = 2.0,
                     kinds: Sequence[str] = ("linear", "14speed", "nonlinear")) -> Path:
    """The first ``seconds`` of the evaluated road (seed 0): SWS of each representation
    (the paper's figure 9) and the road height."""
    i0, _ = result.traces["window"]
    any_run = result.traces[kinds[0]]
    n = int(round(seconds / any_run.dt_s))
    sl = slice(i0, i0 + n)
    t = any_run.time_s[sl] - any_run.time_s[i0]
    fig = new_figure(9.0, 5.6)
    ax_r, ax = fig.subplots(2, 1, sharex=True, height_ratios=[1, 2.4])
    ax_r.plot(t, any_run.road_m[sl] * 1e3, color="0.3", linewidth=1.0)
    ax_r.set_ylabel("road [mm]")
    ax_r.grid(True, alpha=0.35)
    for kind in kinds:
        if kind in result.traces:
            ax.plot(t, result.traces[kind].sws_m[sl] * 1e3, **_line(kind))
    decorate(ax, "time from the start of the evaluated road [s]",
             "SWS [mm] (compression +)")
    ax.set_xlim(0, seconds)
    doc = result.doc
    fig.suptitle(f"Suspension working space, first {seconds:g} s of {doc['title']} "
                 f"(seed 0; cf. the paper's figure 9)", fontsize="medium")
    return _save(fig, path)


def plot_psds(path: str | Path, result: StudyResult, settings: StudySettings,
              kinds: Sequence[str] = ("linear", "14speed", "nonlinear")) -> Path:
    """Welch PSDs (seed 0, evaluated window) of SWS, body acceleration (unweighted and
    Wk-weighted) and DTL per representation, with the linear frequency-domain prediction
    ``|H|² S`` dashed."""
    i0, i1 = result.traces["window"]
    road, car = settings.road, settings.car
    speed = road.speed_m_s
    lo, hi = band_at_speed(road, speed)
    fs = 1.0 / settings.dt_s
    nper = 8192
    fig = new_figure(11.0, 7.6)
    axes = fig.subplots(2, 2).ravel()
    titles = ["SWS [m²/Hz]", "body acceleration, unweighted [(m/s²)²/Hz]",
              "body acceleration, Wk-weighted [(m/s²)²/Hz]", "DTL [kN²/Hz]"]
    f_fd = np.geomspace(lo * speed, hi * speed, 2000)
    s_fd = road.roughness * speed ** (road.waviness - 1) * f_fd ** (-road.waviness)
    h = transfer_functions(car, f_fd)
    w = frequency_weighting("Wk", f_fd)
    fd = [np.abs(h.sws) ** 2 * s_fd, np.abs(h.body_accel) ** 2 * s_fd,
          np.abs(h.body_accel * w) ** 2 * s_fd, np.abs(h.dtl / 1e3) ** 2 * s_fd]
    for kind in kinds:
        if kind not in result.traces:
            continue
        r = result.traces[kind]
        aw = weight_signal("Wk", r.body_accel_m_s2, fs)
        sigs = [r.sws_m, r.body_accel_m_s2, aw, r.dtl_n / 1e3]
        for ax, x in zip(axes, sigs):
            f, p = sps.welch(x[i0:i1], fs=fs, nperseg=nper)
            keep = (f > 0) & (f <= 60)
            ax.loglog(f[keep], p[keep], **_line(kind))
    for ax, y, title in zip(axes, fd, titles):
        ax.loglog(f_fd, y, color="k", linestyle="--", linewidth=1.0,
                  label="linear, frequency domain")
        ax.set_title(title, fontsize="medium")
        ax.set_xlabel("frequency [Hz]")
        ax.set_xlim(0.1, 60)
        ymax = max(line.get_ydata().max() for line in ax.get_lines())
        ax.set_ylim(ymax * 1e-6, ymax * 3)
        _log_grid(ax)
    axes[0].legend(fontsize="small", loc="lower left")
    fig.suptitle(f"Output PSDs (Welch, {nper} samples), {result.doc['title']}, seed 0; "
                 f"road band {lo * speed:.2g}–{hi * speed:.3g} Hz", fontsize="medium")
    return _save(fig, path)


def plot_band_sensitivity(path: str | Path, settings: StudySettings,
                          paper: Mapping[str, float] = PAPER_FIGURE_10["linear"],
                          n_min_values: Sequence[float] = (0.005, 0.01, 0.02, 0.05, 0.1),
                          n_max_values: Sequence[float] = (0.4, 0.6, 0.8, 1.2, 2.0, 10.0)
                          ) -> Path:
    """Linear frequency-domain SWS, weighted acceleration and DTL r.m.s. over the paper's
    figure-10 values, against the band's upper edge (top row, one line per lower edge)
    and its lower edge (bottom row, one line per upper edge); ±10 % shaded, the chosen
    band marked."""
    road, car, speed = settings.road, settings.car, settings.road.speed_m_s
    chosen = road.band_cycles_per_m
    n_max_axis = np.geomspace(0.2, 20.0, 300)
    n_min_axis = np.geomspace(0.002, 0.2, 300)
    top = band_sensitivity(car, road, speed, n_min_values, n_max_axis)
    bottom = band_sensitivity(car, road, speed, n_min_axis, n_max_values)
    keys = [("sws_rms", "SWS r.m.s."), ("accel_w_rms", "weighted accel r.m.s."),
            ("dtl_rms", "DTL r.m.s.")]
    fig = new_figure(12.0, 7.2)
    axes = fig.subplots(2, 3, sharey=True)
    cmap = [f"C{i}" for i in range(10)]
    for j, (key, title) in enumerate(keys):
        ax = axes[0, j]
        for i, lo in enumerate(n_min_values):
            ax.semilogx(n_max_axis, top[key][i] / paper[key], color=cmap[i], linewidth=1.2,
                        label=f"n_min = {lo:g}")
        ax.axvline(chosen[1], color="k", linestyle="--", linewidth=0.9)
        ax.set_xlabel("band upper edge n_max [cycles/m]  (× 20 = Hz)")
        ax.set_title(f"{title} / paper ({paper[key]:g})", fontsize="medium")
        ax = axes[1, j]
        for i, hi in enumerate(n_max_values):
            ax.semilogx(n_min_axis, bottom[key][:, i] / paper[key], color=cmap[i],
                        linewidth=1.2, label=f"n_max = {hi:g}")
        ax.axvline(chosen[0], color="k", linestyle="--", linewidth=0.9)
        ax.set_xlabel("band lower edge n_min [cycles/m]  (× 20 = Hz)")
    for ax in axes.ravel():
        ax.axhspan(0.9, 1.1, color="0.85", zorder=0)
        ax.axhline(1.0, color="0.4", linewidth=0.8)
        ax.set_ylim(0.4, 1.25)
        _log_grid(ax)
    axes[0, 0].set_ylabel("linear car / paper's figure 10")
    axes[1, 0].set_ylabel("linear car / paper's figure 10")
    axes[0, 0].legend(fontsize="small", loc="lower right")
    axes[1, 0].legend(fontsize="small", loc="lower left")
    fig.suptitle(f"Band sensitivity, linear car, frequency domain, {speed:g} m/s "
                 f"(dashed: chosen band {chosen[0]:g}–{chosen[1]:g} cycles/m; "
                 f"grey: ±10 %)", fontsize="medium")
    return _save(fig, path)


# --------------------------------------------------------------------------------------
# figure 11


def plot_speed_sweep(path: str | Path, doc: Mapping[str, Any],
                     settings: StudySettings | None = None) -> Path:
    """Weighted body-acceleration r.m.s. against speed (mean ± std over seeds) per
    representation, the paper's figure-10 values at 20 m/s, and the linear
    frequency-domain prediction for both band scalings when ``settings`` is given."""
    speeds = np.asarray(doc["speeds_m_s"])
    fig = new_figure(11.0, 4.8)
    ax, ax_r = fig.subplots(1, 2, width_ratios=[1.5, 1])
    for kind in doc["representations"]:
        y = np.asarray(doc[kind]["accel_w_rms"])
        e = np.asarray(doc[kind]["accel_w_rms_std"])
        style = _line(kind)
        ax.errorbar(speeds, y, yerr=e, marker="o", markersize=4, capsize=2, **style)
        if kind != "linear" and "linear" in doc:
            ax_r.plot(speeds, y / np.asarray(doc["linear"]["accel_w_rms"]), marker="o",
                      markersize=4, **style)
    for kind, vals in PAPER_FIGURE_10.items():
        if kind in doc["representations"]:
            ax.plot([20.0], [vals["accel_w_rms"]], marker="*", markersize=11, linestyle="",
                    color=COLOURS[kind], markeredgecolor="k", markeredgewidth=0.5)
    ax.plot([], [], marker="*", linestyle="", color="0.6", markeredgecolor="k",
            markersize=11, label="paper, figure 10 (20 m/s)")
    if settings is not None:
        import dataclasses

        from ride_sim.study_linear import linear_prediction
        v = np.linspace(speeds.min(), speeds.max(), 61)
        for scaling, ls in (("temporal", "--"), ("spatial", ":")):
            road = dataclasses.replace(settings.road, band_scaling=scaling)
            y = [linear_prediction(settings.car, road, s, points=4000)["accel_w_rms"]
                 for s in v]
            ax.plot(v, y, color="k", linestyle=ls, linewidth=0.9,
                    label=f"linear, freq. domain, {scaling} band")
    decorate(ax, "speed [m/s]", "weighted body acceleration r.m.s. [m/s²]")
    ax.set_xlim(0, speeds.max() + 2)
    ax.set_ylim(bottom=0)
    ax.set_title(f"Wk-weighted acceleration vs speed ({doc['settings']['road']['seeds']} "
                 f"seeds, band scaling: {doc['settings']['road']['band_scaling']})",
                 fontsize="medium")
    ax_r.axhline(1.0, color=COLOURS["linear"], linewidth=1.0)
    for key in ("crossing_linear_nonlinear_m_s",):
        for c in doc.get(key, []):
            ax_r.axvline(c, color=COLOURS["nonlinear"], linestyle="--", linewidth=0.8)
    ax_r.axvline(20.0, color="0.5", linestyle=":", linewidth=0.8)
    decorate(ax_r, "speed [m/s]", "r.m.s. / linear")
    ax_r.set_title("relative to the linear damper (dashed: crossing; dotted: 20 m/s)",
                   fontsize="small")
    ax_r.set_xlim(0, speeds.max() + 2)
    return _save(fig, path)


# --------------------------------------------------------------------------------------
# figure 13


def plot_pothole(path: str | Path, result: StudyResult,
                 kinds: Sequence[str] = ("linear", "14speed", "nonlinear"),
                 before_s: float = 0.3, after_s: float = 1.7) -> Path:
    """Road (raw and as the tyre sees it), SWS, body acceleration and DTL against time
    over the pothole; the r.m.s. window shaded."""
    tr = result.traces
    speed, t_edge = tr["speed_m_s"], tr["t_edge_s"]
    i0, i1 = tr["window"]
    run0 = tr[kinds[0]]
    t = run0.time_s
    fig = new_figure(10.0, 9.0)
    axes = fig.subplots(4, 1, sharex=True, height_ratios=[0.8, 1, 1, 1])
    raw, env = tr["raw"], tr["enveloped"]
    axes[0].plot(raw.distance_m / speed, raw.height_m * 1e3, color="0.6", linewidth=1.0,
                 label="road")
    axes[0].plot(env.distance_m / speed, env.height_m * 1e3, color="k", linewidth=1.2,
                 label="as the tyre sees it")
    axes[0].set_ylabel("road [mm]")
    axes[0].legend(fontsize="small", loc="lower right")
    axes[0].grid(True, alpha=0.35)
    for kind in kinds:
        r = tr[kind]
        axes[1].plot(t, r.sws_m * 1e3, **_line(kind))
        axes[2].plot(t, r.body_accel_m_s2, **_line(kind))
        axes[3].plot(t, r.dtl_n / 1e3, **_line(kind))
    for ax, label in zip(axes[1:], ["SWS [mm] (compression +)",
                                    "body accel [m/s²] (unweighted)", "DTL [kN]"]):
        ax.axvspan(t[i0], t[min(i1, t.size - 1)], color="0.9", zorder=0)
        decorate(ax, "", label, legend=False)
    axes[1].legend(fontsize="small", loc="lower right")
    axes[3].set_xlabel("time [s]")
    axes[3].set_xlim(t_edge - before_s, t_edge + after_s)
    doc = result.doc
    p = doc["pothole"]
    fig.suptitle(f"Pothole {p['depth_m'] * 1e3:g} mm × {p['length_m']:g} m, sharp edges, "
                 f"tyre R = {p['tyre_radius_m']:g} m, contact {p['contact_length_m']:g} m, "
                 f"{speed:g} m/s (grey: r.m.s. window)", fontsize="medium")
    return _save(fig, path)


# --------------------------------------------------------------------------------------
# the adaptive damper (ride_sim.adaptive_study)

ADAPTIVE_COLOURS = {"sport": "C3", "comfort": "C0", "skyhook": "C2"}


def plot_adaptive_bars(path: str | Path, doc: Mapping[str, Any]) -> Path:
    """SWS, Wk-weighted body acceleration and DTL r.m.s. per case of an adaptive study:
    mean over seeds (bar), ± std (error bar), each seed (dots), ratio to passive sport."""
    from ride_sim.adaptive_study import ADAPTIVE_KEYS

    cases = list(doc["cases"])
    panels = {"sws_rms": ("SWS r.m.s. [mm]", 1e3), "accel_w_rms":
              ("Wk-weighted body accel r.m.s. [m/s²]", 1.0), "dtl_rms": ("DTL r.m.s. [kN]", 1e-3)}
    fig = new_figure(11.0, 4.4)
    axes = fig.subplots(1, len(ADAPTIVE_KEYS))
    x = np.arange(len(cases))
    for ax, key in zip(axes, ADAPTIVE_KEYS):
        label, scale = panels[key]
        means = np.array([doc[c][key] for c in cases]) * scale
        stds = np.array([doc[c]["spread"][key]["std"] for c in cases]) * scale
        ax.bar(x, means, yerr=stds, capsize=5, width=0.6, alpha=0.85,
               color=[ADAPTIVE_COLOURS.get(c, "0.5") for c in cases], edgecolor="k",
               linewidth=0.6, error_kw={"linewidth": 1.2})
        for i, c in enumerate(cases):
            seeds = np.array([m[key] for m in doc[c]["per_seed"]]) * scale
            ax.plot(np.full(seeds.size, i) + np.linspace(-0.15, 0.15, seeds.size), seeds,
                    linestyle="", marker="o", markersize=3, color="k", alpha=0.6)
            ratio = doc.get("ratio_to_sport", {}).get(c, {}).get(key)
            text = "1" if c == "sport" else f"×{ratio['mean']:.3f}"
            ax.annotate(text, (i, means[i] + stds[i]), xytext=(0, 4),
                        textcoords="offset points", ha="center", fontsize="small")
        ax.set_xticks(x, [doc["labels"][c].replace(" (", "\n(") for c in cases],
                      fontsize="small")
        ax.set_ylabel(label)
        ax.set_ylim(0, 1.15 * float(np.max(means + stds)))
        ax.grid(True, axis="y", alpha=0.35)
    seeds = doc[cases[0]]["seeds"]
    fig.suptitle(f"{doc['title']}\nbars: mean ± std over {seeds} seeds; dots: each seed; "
                 f"×: mean per-seed ratio to passive sport", fontsize="medium")
    return _save(fig, path)


def plot_adaptive_history(path: str | Path, result: StudyResult, start_s: float = 5.0,
                          seconds: float = 3.0) -> Path:
    """A segment of seed 0 (``start_s`` into the evaluated road, ``seconds`` long):
    Wk-weighted body acceleration of the three cases, the skyhook run's body and damper
    velocities, and its valve command (commanded, held at the controller rate, and
    effective after the solenoid lag)."""
    tr = result.traces
    i0, i1 = tr["window"]
    sky = tr["skyhook"]
    dt = sky.result.dt_s
    a = i0 + int(round(start_s / dt))
    b = min(i1, a + int(round(seconds / dt)))
    sl = slice(a, b)
    t = sky.result.time_s[sl] - sky.result.time_s[i0]
    fig = new_figure(10.0, 8.0)
    ax_a, ax_v, ax_c = fig.subplots(3, 1, sharex=True, height_ratios=[1.3, 1, 0.9])
    for case in result.doc["cases"]:
        r = tr[case].result
        aw = weight_signal("Wk", r.body_accel_m_s2, 1.0 / r.dt_s)
        rms = result.doc[case]["per_seed"][0]["accel_w_rms"]
        ax_a.plot(t, aw[sl], color=ADAPTIVE_COLOURS.get(case, "0.5"),
                  linewidth=1.4 if case == "skyhook" else 1.0,
                  label=f"{result.doc['labels'][case]}: r.m.s. {rms:.2f} m/s²")
    decorate(ax_a, "", "Wk-weighted body accel [m/s²]")
    lo, hi = ax_a.get_ylim()
    ax_a.set_ylim(lo, hi + 0.3 * (hi - lo))           # room for the legend
    ax_a.legend(loc="upper center", fontsize="small", ncol=3)
    r = sky.result
    ax_v.plot(t, r.body_velocity_m_s[sl], color="k", linewidth=1.0,
              label="body velocity z2' (up +)")
    ax_v.plot(t, r.damper_velocity_m_s[sl], color="C1", linewidth=1.0,
              label="damper velocity (extension +)")
    both = r.body_velocity_m_s[sl] * r.damper_velocity_m_s[sl] > 0
    ax_v.fill_between(t, 0, 1, where=both, color="C2", alpha=0.12, linewidth=0,
                      transform=ax_v.get_xaxis_transform(),
                      label="same sign: skyhook force achievable")
    decorate(ax_v, "", "skyhook run [m/s]")
    lo, hi = ax_v.get_ylim()
    ax_v.set_ylim(lo, hi + 0.35 * (hi - lo))
    ax_v.legend(loc="upper center", fontsize="small", ncol=3)
    ax_c.step(t, tr["skyhook"].command[sl], where="post", color="0.5", linewidth=0.9,
              label=f"commanded ({result.doc['controller']['update_rate_hz']:g} Hz, held)")
    ax_c.plot(t, tr["skyhook"].effective_command[sl], color="C2", linewidth=1.4,
              label="effective (solenoid lag)")
    decorate(ax_c, "time from the start of the evaluated road [s]",
             "valve command\n(0 comfort, 1 sport)")
    ax_c.set_ylim(-0.05, 1.35)
    ax_c.legend(loc="upper center", fontsize="small", ncol=2)
    ax_c.set_xlim(t[0], t[-1])
    fig.suptitle(f"Skyhook vs passive, {seconds:g} s of seed 0\n{result.doc['title']}",
                 fontsize="medium")
    return _save(fig, path)
