#!/usr/bin/env python3
"""Survey of the FSAE TTX25 dyno files: figures, sign evidence, gas force, friction, fade.

Reads every vendor file under the data folder (default
``../shared/data/measured/fsae_ttx25`` next to the repository) with
:func:`damper_emulator.dyno.fsae.read_fsae_ttx25`, and writes

* the generated tables of ``docs/measured/fsae_ttx25_data.md`` (between the
  ``<!-- survey:begin -->`` and ``<!-- survey:end -->`` markers; the prose around them is
  kept),
* the plots ``docs/measured/fsae_*.png``,
* with ``--json FILE``, every figure in machine-readable form.

The data are read at run time and never copied: only derived figures are written.

Usage: ``.venv/bin/python tools/fsae_survey.py [--data DIR] [--doc FILE] [--plots DIR]
[--json FILE]``
"""

from __future__ import annotations

import argparse
import csv
import gzip
import itertools
import json
import math
import sys
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from scipy.signal import medfilt, savgol_filter

from damper_emulator.dyno.fsae import (
    CONNECTING_ROD_M,
    CRANK_RADIUS_M,
    FORCE_N_PER_V,
    PSI_TO_PA,
    SAVGOL_POLYORDER,
    SAVGOL_WINDOW,
    STROKE_M,
    cycle_starts,
    cycle_work,
    fsae_files,
    parse_fsae_name,
    read_fsae_ttx25,
)

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "measured" / "fsae_ttx25"
DEFAULT_DOC = REPO / "docs" / "measured" / "fsae_ttx25_data.md"
BEGIN, END = "<!-- survey:begin -->", "<!-- survey:end -->"
P_ATM = 101325.0
#: half-width of the mid-stroke window [m] and the velocity threshold of the s1 fit [m/s]
MID_WINDOW_M = 0.5e-3
S1_FIT_MIN_SPEED = 5e-3
#: trailing rest: |v| below this [m/s] for at least REST_MIN_S
REST_SPEED = 1e-3
REST_MIN_S = 0.3
DPI = 110


# --------------------------------------------------------------------------------------
# per-file figures


def vendor_force_slope(path: Path) -> float:
    """Median ``Force (N) / Force (V)`` of the vendor file (the slope the vendor used)."""
    opener = gzip.open if path.read_bytes()[:2] == b"\x1f\x8b" else open
    with opener(path, "rt", encoding="utf-8-sig", newline="") as fh:
        rows = csv.reader(fh)
        head = [h.strip().lower() for h in next(rows)]
        iv, iN = head.index("force (v)"), head.index("force (n)")
        r = [float(f[iN]) / float(f[iv]) for f, _ in zip(rows, range(2000))
             if abs(float(f[iv])) > 0.05]
    return float(np.median(r))


def harmonics(x: np.ndarray, t: np.ndarray, f0: float, n: int = 4) -> list[float]:
    """Amplitudes of the first ``n`` harmonics of ``f0`` in ``x`` (least squares)."""
    cols = [np.ones_like(t)]
    for k in range(1, n + 1):
        cols += [np.cos(2 * np.pi * k * f0 * t), np.sin(2 * np.pi * k * f0 * t)]
    c, *_ = np.linalg.lstsq(np.column_stack(cols), x, rcond=None)
    return [float(math.hypot(c[2 * k - 1], c[2 * k])) for k in range(1, n + 1)]


def spike(y: np.ndarray) -> float:
    """Largest deviation from a 5-sample running median (isolated spikes show, steps do
    not)."""
    return float(np.max(np.abs(y - medfilt(y, 5))))


def reversal_lag(x: np.ndarray, f: np.ndarray, a: int, b: int, top: bool) -> float:
    """Travel [m] after the stroke end in ``[a, b)`` (maximum when ``top``) until the force
    has covered half its change from the end to mid-stroke."""
    seg_x, seg_f = x[a:b], f[a:b]
    i = int(np.argmax(seg_x) if top else np.argmin(seg_x))
    after = slice(i, None)
    xs, fs = seg_x[after], seg_f[after]
    mid = np.flatnonzero(np.abs(xs) < MID_WINDOW_M)
    if mid.size == 0:
        return float("nan")
    target = 0.5 * (fs[0] + fs[mid[0]])
    cross = np.flatnonzero((fs <= target) if top else (fs >= target))
    return float(abs(xs[0] - xs[cross[0]])) if cross.size else float("nan")


def dwell(x: np.ndarray, v: np.ndarray, a: int, b: int) -> tuple[float, float]:
    """Fractions of the cycle with |v| < 10 % of its peak near the x-max and x-min ends."""
    slow = np.abs(v[a:b]) < 0.1 * np.abs(v[a:b]).max()
    n = b - a
    return float(np.sum(slow & (x[a:b] > 0)) / n), float(np.sum(slow & (x[a:b] < 0)) / n)


def fit_s1(d, sel) -> dict:
    """Least-squares ``F = F0 + k x + Ff sgn(v) + c v`` on the samples ``sel``."""
    x, v, f = d.displacement[sel], d.velocity[sel], d.force[sel]
    A = np.column_stack([np.ones_like(x), x, np.sign(v), v])
    c, *_ = np.linalg.lstsq(A, f, rcond=None)
    r = f - A @ c
    return {"F0_N": float(c[0]), "k_N_per_m": float(c[1]), "friction_N": float(c[2]),
            "c_N_s_per_m": float(c[3]), "rms_N": float(np.sqrt(np.mean(r ** 2)))}


def survey_file(path: Path, root: Path):
    """``(figures, data)`` of one vendor file."""
    d = read_fsae_ttx25(path)
    info = parse_fsae_name(path)
    t, x, v, f, temp = d.time, d.displacement, d.velocity, d.force, d.temperature
    s = cycle_starts(d)
    w = cycle_work(d, s)
    full = slice(int(s[0]), int(s[-1]))
    periods = np.diff(t[s])
    freq = float(1.0 / np.median(periods))
    xs = savgol_filter(x, SAVGOL_WINDOW, SAVGOL_POLYORDER)
    stroke = float(xs.max() - xs.min())
    half = 0.5 * stroke

    # per-cycle extremes and mid-stroke forces
    vmax, vmin, fmax, fmin, f_ext, f_com, v_ext, v_com, t_cyc = ([] for _ in range(9))
    lag_c, lag_r, dw_top, dw_bot, f_avg, tm_cyc = [], [], [], [], [], []
    for a, b in itertools.pairwise(s):
        a, b = int(a), int(b)
        sl = slice(a, b)
        # compression starts at the x-max end, rebound at the x-min end (which comes
        # after mid-stroke-down, so search from the cycle's middle onwards)
        lag_c.append(reversal_lag(x, f, a, b, top=True))
        nxt = int(s[min(np.searchsorted(s, b) + 1, len(s) - 1)])
        lag_r.append(reversal_lag(x, f, a + (b - a) // 2, nxt if nxt > b else b, top=False))
        d1, d2 = dwell(x, v, a, b)
        dw_top.append(d1)
        dw_bot.append(d2)
        vmax.append(v[sl].max())
        vmin.append(v[sl].min())
        fmax.append(f[sl].max())
        fmin.append(f[sl].min())
        mid = np.abs(x[sl]) < MID_WINDOW_M
        ext, com = mid & (v[sl] > 0), mid & (v[sl] < 0)
        f_ext.append(f[sl][ext].mean())
        f_com.append(f[sl][com].mean())
        v_ext.append(v[sl][ext].mean())
        v_com.append(v[sl][com].mean())
        t_cyc.append(temp[sl].mean())
        tm_cyc.append(0.5 * (t[a] + t[b]))
        f_avg.append(0.5 * (f_ext[-1] + f_com[-1]))
    med = lambda a: float(np.nanmedian(a))  # noqa: E731
    f_mid_ext, f_mid_com = med(f_ext), med(f_com)

    # trailing rest (the files start in motion; some end at rest)
    moving = np.flatnonzero(np.abs(v) >= REST_SPEED)
    tail = len(v) - 1 - int(moving[-1]) if moving.size else len(v)
    rest = None
    if tail * np.median(np.diff(t)) >= REST_MIN_S:
        rest = {"force_N": float(np.median(f[-tail:])),
                "x_mm": float(np.median(x[-tail:]) * 1e3)}

    h = harmonics(x[full] - x[full].mean(), t[full] - t[full][0], freq)
    hv = harmonics(v[full], t[full] - t[full][0], freq)
    sec = int(round(1.0 / np.median(np.diff(t))))
    raw_sign = -np.sign(np.sum(w))  # FORCE_SIGN × DISPLACEMENT_SIGN = -1
    out = {
        "file": str(path.relative_to(root)),
        "name": info.name,
        "trial": info.trial, "valves": info.valve_label, "speed_code": info.speed_code,
        "cycles_in_name": info.cycles, "gas_psi": info.gas_psi, "heat_gun": info.heat_gun,
        "samples": len(d), "duration_s": d.duration_s,
        "sample_rate_hz": float((len(d) - 1) / d.duration_s),
        "full_cycles": int(len(w)), "frequency_hz": freq,
        "period_spread": float((periods.max() - periods.min()) / np.median(periods)),
        "stroke_mm": stroke * 1e3,
        "v_peak_ext_m_s": med(vmax), "v_peak_com_m_s": med(vmin),
        "force_max_N": med(fmax), "force_min_N": med(fmin),
        "work_per_cycle_J": float(np.mean(w)), "work_min_J": float(w.min()),
        "work_max_J": float(w.max()),
        "c_eq_N_s_per_m": float(np.mean(w) / (np.pi * 2 * np.pi * freq * half ** 2)),
        "loop_fullness": float(np.mean(w) / ((med(fmax) - med(fmin)) * stroke)),
        "positive_cycles": int(np.sum(w > 0)),
        "vendor_product_sign": int(raw_sign),
        "vendor_force_slope_N_per_V": vendor_force_slope(path),
        "temp_start_C": float(np.median(temp[:sec])), "temp_end_C": float(np.median(temp[-sec:])),
        "temp_min_C": float(np.min(savgol_filter(temp, 301, 1))),
        "temp_max_C": float(np.max(savgol_filter(temp, 301, 1))),
        "f_mid_ext_N": f_mid_ext, "f_mid_com_N": f_mid_com,
        "v_mid_ext_m_s": med(v_ext), "v_mid_com_m_s": med(v_com),
        "f_mid_avg_N": 0.5 * (f_mid_ext + f_mid_com),
        "rest_end": rest,
        "x_harmonics_ratio": [a / h[0] for a in h[1:]],
        "v_harmonics_ratio": [a / hv[0] for a in hv[1:]],
        "spike_force_N": spike(f), "spike_displacement_mm": spike(x) * 1e3,
        "lag_compression_mm": med(lag_c) * 1e3, "lag_rebound_mm": med(lag_r) * 1e3,
        "dwell_xmax": med(dw_top), "dwell_xmin": med(dw_bot),
        "force_volts_range": [float(f.min() / -FORCE_N_PER_V), float(f.max() / -FORCE_N_PER_V)],
        "cycle_temp_C": [float(a) for a in t_cyc],
        "cycle_time_s": [float(a) for a in tm_cyc],
        "cycle_work_J": [float(a) for a in w],
        "cycle_force_max_N": [float(a) for a in fmax],
        "cycle_force_min_N": [float(a) for a in fmin],
        "cycle_f_mid_avg_N": [float(a) for a in f_avg],
    }
    if info.speed_code == 1:
        sel = np.zeros(len(d), bool)
        sel[full] = True
        out["s1_fit"] = fit_s1(d, sel & (np.abs(v) > S1_FIT_MIN_SPEED))
    return out, d


# --------------------------------------------------------------------------------------
# cross-file analyses


def gas_analysis(runs: list[dict]) -> dict:
    """Static force against gas charge on the one valve setting tested at several charges."""
    same = [r for r in runs if r["valves"] == "1_1_18_18"]
    points = []
    for r in same:
        est = r["s1_fit"]["F0_N"] if "s1_fit" in r else r["f_mid_avg_N"]
        points.append({"name": r["name"], "speed_code": r["speed_code"], "gas_psi": r["gas_psi"],
                       "estimator": "s1 fit F0" if "s1_fit" in r else "mid-stroke average",
                       "static_N": est})
    out: dict = {"points": points}
    # through the origin, from the slow runs (least viscous contamination)
    s1 = [(q["gas_psi"] * PSI_TO_PA, q["static_N"]) for q in points if q["speed_code"] == 1]
    if s1:
        P, F = np.array(s1).T
        a = -float(np.sum(F * P) / np.sum(P * P))
        out["area_s1_origin_m2"] = a
    for code in (1, 5):
        pts = sorted((q["gas_psi"] * PSI_TO_PA, q["static_N"]) for q in points
                     if q["speed_code"] == code)
        if len(pts) >= 2:
            P, F = np.array(pts).T
            slope, icpt = np.polyfit(P, F, 1)
            out[f"s{code}_pair"] = {"area_m2": float(-slope), "intercept_N": float(icpt)}
    # gas spring: k = n P_abs A^2 / V  ->  V for n = 1 (isothermal) and 1.4 (adiabatic)
    area = out.get("area_s1_origin_m2")
    springs = []
    for r in same:
        if "s1_fit" in r and area:
            pabs = r["gas_psi"] * PSI_TO_PA + P_ATM
            k = r["s1_fit"]["k_N_per_m"]
            springs.append({"gas_psi": r["gas_psi"], "k_N_per_m": k,
                            "V_gas_iso_m3": pabs * area ** 2 / k,
                            "V_gas_adiabatic_m3": 1.4 * pabs * area ** 2 / k})
    out["gas_spring"] = springs
    return out


def fade_analysis(r: dict) -> dict:
    """Per-cycle force and dissipated energy against temperature (linear fit)."""
    T = np.array(r["cycle_temp_C"])
    out = {"name": r["name"], "T_first_C": float(T[:5].mean()), "T_last_C": float(T[-5:].mean())}
    for key, lab in (("cycle_force_max_N", "rebound_peak"),
                     ("cycle_force_min_N", "compression_peak"),
                     ("cycle_work_J", "work"), ("cycle_f_mid_avg_N", "mid_avg")):
        y = np.array(r[key])
        first, last = float(y[:5].mean()), float(y[-5:].mean())
        slope = float(np.polyfit(T, y, 1)[0])
        out[lab] = {"first": first, "last": last, "change_pct": 100 * (last - first) / abs(first),
                    "slope_per_C": slope, "slope_pct_per_C": 100 * slope / abs(first)}
    return out


# --------------------------------------------------------------------------------------
# plots


def _figure(w: float, h: float, ncols: int = 1, nrows: int = 1):
    fig = Figure(figsize=(w, h), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axs = fig.subplots(nrows, ncols, squeeze=False)
    return fig, axs.ravel()


def _one_cycle(d, k: int = 2):
    s = cycle_starts(d)
    k = min(k, len(s) - 2)
    return slice(int(s[k]), int(s[k + 1]) + 1)


def plot_loops(data: dict, out: Path) -> Path:
    sel = [("t1_1_1_18_18_s1_n10_100psi", "s1 (0.21 Hz), 100 psi", "tab:blue"),
           ("t1_1_1_18_18_s5_n10_50psi", "s5 (1.05 Hz), 50 psi", "tab:green"),
           ("t1_1_1_18_18_s5_n10_150psi", "s5 (1.05 Hz), 150 psi", "tab:olive"),
           ("t1_1_1_18_18_s6_n10_100psi", "s6 (1.25 Hz), 100 psi", "tab:red")]
    fig, (a1, a2) = _figure(11.5, 4.6, ncols=2)
    for name, label, color in sel:
        d = data.get(name)
        if d is None:
            continue
        s = cycle_starts(d)
        full = slice(int(s[0]), int(s[-1]))
        one = _one_cycle(d)
        for ax, xx in ((a1, d.displacement * 1e3), (a2, d.velocity)):
            ax.plot(xx[full], d.force[full], color=color, lw=0.4, alpha=0.35)
            ax.plot(xx[one], d.force[one], color=color, lw=1.6, label=label)
    a1.set_xlabel("displacement from mid-stroke [mm] (extension +)")
    a2.set_xlabel("velocity [m/s] (extension +)")
    for ax in (a1, a2):
        ax.set_ylabel("force [N] (rebound +)")
        ax.grid(True, alpha=0.35)
        ax.axhline(0, color="k", lw=0.6)
        ax.axvline(0, color="k", lw=0.6)
    a1.set_title("force–displacement, valves 1_1_18_18")
    a2.set_title("force–velocity, valves 1_1_18_18")
    a2.legend(loc="upper left", fontsize=8, title="one cycle bold, all cycles thin",
              title_fontsize=8)
    return _save(fig, out)


def plot_static(gas: dict, out: Path) -> Path:
    fig, (ax,) = _figure(6.2, 4.2)
    marks = {1: ("o", "s1 fit F0 (0.21 Hz)"), 5: ("s", "s5 mid-stroke average (1.05 Hz)"),
             6: ("^", "s6 mid-stroke average (1.25 Hz)")}
    seen = set()
    for q in gas["points"]:
        m, lab = marks[q["speed_code"]]
        ax.plot(q["gas_psi"], q["static_N"], m, ms=8, color=f"C{q['speed_code'] % 7}",
                label=None if q["speed_code"] in seen else lab)
        seen.add(q["speed_code"])
    a = gas.get("area_s1_origin_m2")
    if a:
        psi = np.linspace(0, 160, 50)
        ax.plot(psi, -a * psi * PSI_TO_PA, "k--", lw=1,
                label=f"−A·P, A = {a * 1e6:.1f} mm² "
                      f"(d = {math.sqrt(4 * a / math.pi) * 1e3:.1f} mm)")
    ax.set_xlabel("nitrogen charge [psi gauge]")
    ax.set_ylabel("static force [N] (rebound +)")
    ax.set_title("gas force vs charge, valves 1_1_18_18")
    ax.grid(True, alpha=0.35)
    ax.set_xlim(0, 160)
    ax.legend(fontsize=8, loc="lower left")
    return _save(fig, out)


def plot_heat_gun(d, r: dict, out: Path) -> Path:
    fig, (a1, a2) = _figure(11.5, 4.6, ncols=2)
    s = cycle_starts(d)
    full = slice(int(s[0]), int(s[-1]))
    T = savgol_filter(d.temperature, 301, 1)[full]
    v, f = d.velocity[full], d.force[full]
    seg = np.stack([np.column_stack([v[:-1], f[:-1]]), np.column_stack([v[1:], f[1:]])], axis=1)
    lc = LineCollection(seg, cmap="inferno", linewidths=0.5)
    lc.set_array(T[:-1])
    a1.add_collection(lc)
    a1.autoscale()
    cb = fig.colorbar(lc, ax=a1)
    cb.set_label("body temperature [°C]")
    a1.set_xlabel("velocity [m/s] (extension +)")
    a1.set_ylabel("force [N] (rebound +)")
    a1.set_title(f"{r['name']}: all {r['full_cycles']} cycles")
    a1.grid(True, alpha=0.35)
    tc = np.array(r["cycle_time_s"])
    for key, lab, m, c, sign in (("cycle_force_max_N", "rebound peak force", "o", "tab:red", 1),
                                 ("cycle_force_min_N", "compression peak force", "s",
                                  "tab:blue", -1),
                                 ("cycle_work_J", "energy per cycle", "^", "tab:gray", 1)):
        y = sign * np.array(r[key])
        ref = y[:5].mean()
        unit = f"{ref:.2f} J" if "work" in key else f"{ref:.0f} N"
        a2.plot(tc, 100 * (y - ref) / ref, m, ms=3.5, color=c,
                label=f"{lab} (first 5 cycles {unit})")
    a2.axhline(0, color="k", lw=0.6)
    a2.set_xlabel("time [s]")
    a2.set_ylabel("change from the first 5 cycles [%] (magnitudes)")
    a2.grid(True, alpha=0.35)
    a3 = a2.twinx()
    a3.plot(d.time[full], T, color="tab:orange", lw=1.0, label="body temperature [°C]")
    a3.set_ylabel("body temperature [°C]", color="tab:orange")
    h1, l1 = a2.get_legend_handles_labels()
    h2, l2 = a3.get_legend_handles_labels()
    a2.legend(h1 + h2, l1 + l2, fontsize=7.5, loc="lower left")
    a2.set_title("per-cycle fade over the run")
    return _save(fig, out)


def plot_valves(data: dict, out: Path) -> Path:
    sel = [("t2_2_2_12_12_s5_n100_100psi_with_heat_gun", "2_2_12_12, 100 psi"),
           ("t1_2_2_24_24_s5_n10_100psi", "2_2_24_24, 100 psi"),
           ("t1_3_3_24_24_s5_n10_100psi", "3_3_24_24, 100 psi"),
           ("t1_1_1_18_18_s5_n10_50psi", "1_1_18_18, 50 psi"),
           ("t1_2_2_18_18_s5_n10_50psi", "2_2_18_18, 50 psi"),
           ("t1_3_3_18_18_s5_n100_50psi", "3_3_18_18, 50 psi")]
    fig, (ax,) = _figure(7.5, 5.0)
    for i, (name, label) in enumerate(sel):
        d = data.get(name)
        if d is None:
            continue
        one = _one_cycle(d)
        ax.plot(d.velocity[one], d.force[one], lw=1.3, color=f"C{i}", label=label)
    ax.set_xlabel("velocity [m/s] (extension +)")
    ax.set_ylabel("force [N] (rebound +)")
    ax.set_title("s5 (1.05 Hz) loops by valve setting a_b_c_d (one cycle each)")
    ax.grid(True, alpha=0.35)
    ax.axhline(0, color="k", lw=0.6)
    ax.axvline(0, color="k", lw=0.6)
    ax.legend(fontsize=8, loc="upper left")
    return _save(fig, out)


def _save(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    return path


# --------------------------------------------------------------------------------------
# markdown


def _f(v, fmt="{:.1f}"):
    return "–" if v is None else fmt.format(v)


def tables(runs: list[dict], gas: dict, fades: list[dict]) -> str:
    L = []
    L.append("### Per-file figures (full cycles only)\n")
    L.append("| file | valves | s | psi | dur. [s] | cycles | f [Hz] | stroke [mm] | "
             "v ext / com [m/s] | F max / min [N] | W/cycle [J] | c_eq [N·s/m] | "
             "T start → end (max) [°C] |")
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in runs:
        L.append(
            f"| {r['file']} | {r['valves']} | {r['speed_code']} | {r['gas_psi']:.0f}"
            f"{' HG' if r['heat_gun'] else ''} | {r['duration_s']:.1f} | {r['full_cycles']} | "
            f"{r['frequency_hz']:.3f} | {r['stroke_mm']:.2f} | "
            f"{r['v_peak_ext_m_s']:.3f} / {r['v_peak_com_m_s']:.3f} | "
            f"{r['force_max_N']:.0f} / {r['force_min_N']:.0f} | {r['work_per_cycle_J']:.2f} | "
            f"{r['c_eq_N_s_per_m']:.0f} | {r['temp_start_C']:.1f} → {r['temp_end_C']:.1f} "
            f"({r['temp_max_C']:.1f}) |")
    L.append("\nHG: with heat gun. W: ∮F dx per cycle (mean). c_eq: linear damping rate that "
             "dissipates the same energy, W/(π ω X²) with X half the measured stroke.\n")

    L.append("### Sign evidence per file\n")
    L.append("| file | vendor Force(N)/Force(V) | sign ∮ V_F dV_x (raw volts) | cycles with "
             "W > 0 | W min … max [J] | loop fullness | F at rest after the run [N] @ x [mm] |")
    L.append("|---|---|---|---|---|---|---|")
    for r in runs:
        rest = r["rest_end"]
        rs = f"{rest['force_N']:.1f} @ {rest['x_mm']:+.1f}" if rest else "(ends moving)"
        L.append(f"| {r['name']} | {r['vendor_force_slope_N_per_V']:+.2f} | "
                 f"{'−' if r['vendor_product_sign'] < 0 else '+'} | "
                 f"{r['positive_cycles']}/{r['full_cycles']} | {r['work_min_J']:.2f} … "
                 f"{r['work_max_J']:.2f} | {r['loop_fullness']:.2f} | {rs} |")
    L.append("\nLoop fullness: W / ((F max − F min) × stroke); 1 is a rectangle, 0.785 an "
             "ellipse.\n")

    L.append("### Force at mid-stroke (x = 0 ± 0.5 mm), median over cycles\n")
    L.append("| file | v ext [m/s] | F ext [N] | v com [m/s] | F com [N] | (F ext + F com)/2 "
             "[N] | F ext − F_gas [N] | F com − F_gas [N] |")
    L.append("|---|---|---|---|---|---|---|---|")
    area = gas.get("area_s1_origin_m2", 0.0)
    for r in runs:
        fg = -area * r["gas_psi"] * PSI_TO_PA
        L.append(f"| {r['name']} | {r['v_mid_ext_m_s']:.3f} | {r['f_mid_ext_N']:.0f} | "
                 f"{r['v_mid_com_m_s']:.3f} | {r['f_mid_com_N']:.0f} | {r['f_mid_avg_N']:.1f} | "
                 f"{r['f_mid_ext_N'] - fg:.0f} | {r['f_mid_com_N'] - fg:.0f} |")
    L.append(f"\nF_gas = −A·P with the A of the gas-force fit below "
             f"({area * 1e6:.1f} mm²).\n")

    L.append("### Gas force against charge (valves 1_1_18_18)\n")
    L.append("| run | speed | psi | estimator | static force [N] |")
    L.append("|---|---|---|---|---|")
    for q in gas["points"]:
        L.append(f"| {q['name']} | s{q['speed_code']} | {q['gas_psi']:.0f} | {q['estimator']} | "
                 f"{q['static_N']:.1f} |")
    L.append("")
    if area:
        L.append(f"- Through the origin, s1 runs: A_eff = {area * 1e6:.1f} mm² "
                 f"(equivalent rod diameter {math.sqrt(4 * area / math.pi) * 1e3:.2f} mm).")
    for code in (1, 5):
        p = gas.get(f"s{code}_pair")
        if p:
            L.append(f"- s{code} pair, straight line: A_eff = {p['area_m2'] * 1e6:.1f} mm² "
                     f"(d = {math.sqrt(4 * max(p['area_m2'], 0) / math.pi) * 1e3:.2f} mm), "
                     f"intercept at 0 psi {p['intercept_N']:+.1f} N.")
    for g in gas["gas_spring"]:
        L.append(f"- Gas-spring slope at {g['gas_psi']:.0f} psi: k = {g['k_N_per_m']:.0f} N/m → "
                 f"implied gas volume {g['V_gas_iso_m3'] * 1e6:.1f} cm³ (isothermal) … "
                 f"{g['V_gas_adiabatic_m3'] * 1e6:.1f} cm³ (adiabatic).")
    L.append("")

    L.append("### Slow runs (s1): F = F0 + k x + F_f sgn(v) + c v, samples with |v| > "
             f"{S1_FIT_MIN_SPEED * 1e3:.0f} mm/s\n")
    L.append("| run | F0 [N] | k [N/mm] | F_f friction [N] | c [N·s/m] | r.m.s. residual [N] |")
    L.append("|---|---|---|---|---|---|")
    for r in runs:
        if "s1_fit" in r:
            q = r["s1_fit"]
            L.append(f"| {r['name']} | {q['F0_N']:.1f} | {q['k_N_per_m'] / 1e3:.3f} | "
                     f"{q['friction_N']:.1f} | {q['c_N_s_per_m']:.0f} | {q['rms_N']:.1f} |")
    L.append("")

    L.append("### Temperature and force fade (per-cycle, first 5 vs last 5 cycles; slope of a "
             "straight-line fit against cycle-mean temperature)\n")
    L.append("| run | T [°C] | rebound peak [N] | compression peak [N] | W/cycle [J] | "
             "W slope [%/°C] | mid-stroke (F ext + F com)/2 [N] |")
    L.append("|---|---|---|---|---|---|---|")
    for q in fades:
        rb, cp, w, m = q["rebound_peak"], q["compression_peak"], q["work"], q["mid_avg"]
        L.append(f"| {q['name']} | {q['T_first_C']:.1f} → {q['T_last_C']:.1f} | "
                 f"{rb['first']:.0f} → {rb['last']:.0f} ({rb['change_pct']:+.1f} %) | "
                 f"{cp['first']:.0f} → {cp['last']:.0f} ({cp['change_pct']:+.1f} %) | "
                 f"{w['first']:.2f} → {w['last']:.2f} ({w['change_pct']:+.1f} %) | "
                 f"{w['slope_pct_per_C']:+.2f} | {m['first']:.1f} → {m['last']:.1f} |")
    L.append("")

    L.append("### Signal quality\n")
    L.append("| file | x harmonics 2/3/4 [% of 1st] | v harmonics 2/3/4 [% of 1st] | "
             "dwell x-max / x-min end [% of period] | half-force travel after reversal: "
             "compression / rebound [mm] | largest spike F [N] / x [mm] | Force (V) range [V] |")
    L.append("|---|---|---|---|---|---|---|")
    for r in runs:
        hx = " / ".join(f"{100 * a:.1f}" for a in r["x_harmonics_ratio"][:3])
        hv = " / ".join(f"{100 * a:.1f}" for a in r["v_harmonics_ratio"][:3])
        lo, hi = sorted(r["force_volts_range"])
        L.append(f"| {r['name']} | {hx} | {hv} | {100 * r['dwell_xmax']:.1f} / "
                 f"{100 * r['dwell_xmin']:.1f} | {r['lag_compression_mm']:.1f} / "
                 f"{r['lag_rebound_mm']:.1f} | {r['spike_force_N']:.1f} / "
                 f"{r['spike_displacement_mm']:.2f} | {lo:.2f} … {hi:.2f} |")
    L.append(f"\nSlider-crank (r = {CRANK_RADIUS_M * 1e3:.2f} mm, L = {CONNECTING_ROD_M * 1e3:.1f} "
             f"mm) at constant crank speed: 2nd harmonic of x = r/(4L) = "
             f"{100 * CRANK_RADIUS_M / (4 * CONNECTING_ROD_M):.1f} % of the 1st, of v twice "
             f"that; nominal stroke {STROKE_M * 1e3:.1f} mm. Dwell: share of the period with "
             f"|v| below 10 % of its peak, near each end (a sine: 3.2 % at each end; this "
             f"slider-crank at constant speed: 3.7 % at the end nearer the crank, 2.8 % at the "
             f"other). Half-force travel: displacement after a stroke end until the force has "
             f"covered half its change from the end value to the mid-stroke value. Largest "
             f"spike: deviation from a 5-sample running median.\n")
    return "\n".join(L)


def update_doc(doc: Path, body: str) -> None:
    note = "<!-- generated by tools/fsae_survey.py; do not edit by hand -->"
    block = f"{BEGIN}\n{note}\n\n{body}\n{END}"
    if doc.exists():
        text = doc.read_text(encoding="utf-8")
        if BEGIN in text and END in text:
            head, rest = text.split(BEGIN, 1)
            _, tail = rest.split(END, 1)
            doc.write_text(head + block + tail, encoding="utf-8")
            return
        doc.write_text(text.rstrip() + "\n\n" + block + "\n", encoding="utf-8")
        return
    doc.parent.mkdir(parents=True, exist_ok=True)
    doc.write_text("# FSAE TTX25 dyno data\n\n" + block + "\n", encoding="utf-8")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="vendor data folder")
    ap.add_argument("--doc", type=Path, default=DEFAULT_DOC, help="markdown file to update")
    ap.add_argument("--plots", type=Path, default=DEFAULT_DOC.parent, help="PNG folder")
    ap.add_argument("--json", type=Path, help="write all figures as JSON")
    a = ap.parse_args(argv)
    files = fsae_files(a.data)
    if not files:
        print(f"fsae_survey: no FSAE files under {a.data}", file=sys.stderr)
        return 2
    runs, data = [], {}
    for i, p in enumerate(files, 1):
        print(f"[{i}/{len(files)}] {p.relative_to(a.data)}", file=sys.stderr)
        r, d = survey_file(p, a.data)
        runs.append(r)
        data[r["name"]] = d
    runs.sort(key=lambda r: (r["file"].count("/") == 0, r["file"]))
    gas = gas_analysis(runs)
    fades = [fade_analysis(r) for r in runs if r["cycles_in_name"] >= 100]
    update_doc(a.doc, tables(runs, gas, fades))
    plots = [plot_loops(data, a.plots / "fsae_loops_1_1_18_18.png"),
             plot_static(gas, a.plots / "fsae_gas_force.png"),
             plot_valves(data, a.plots / "fsae_valve_settings_s5.png")]
    # the heat-gun run whose rebound peak force fades most
    hg = min((r for r in runs if r["heat_gun"]),
             key=lambda r: fade_analysis(r)["rebound_peak"]["change_pct"], default=None)
    if hg:
        plots.append(plot_heat_gun(data[hg["name"]], hg, a.plots / "fsae_heat_gun_fade.png"))
    if a.json:
        a.json.write_text(json.dumps({"runs": runs, "gas": gas, "fade": fades}, indent=1))
    print(f"wrote {a.doc} and {', '.join(str(p) for p in plots)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
