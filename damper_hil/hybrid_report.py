"""The report of a damper-in-the-loop run (``damper-hil hybrid``): plots and report.md.

``hybrid_tracking.png``: the car's stroke (target), the demand and the measured stroke over
the ride and over a close-up, and the tracking error; ``hybrid_force.png``: the measured
force and the twin's, and the twin's residual with its running r.m.s.;
``hybrid_transfer.png``: the identification's demand, measurement and fitted model.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.dyno.plots import decorate, new_figure, save
from damper_emulator.outputs import write_text
from ride_sim.hybrid.criteria import TWIN_WINDOW_S
from ride_sim.hybrid.host import HybridHost
from ride_sim.hybrid.transfer import response

#: Length of the close-up [s] and of the running r.m.s. [s].
CLOSE_UP_S = 1.0
RUNNING_RMS_S = 1.0


def _running_rms(x: np.ndarray, n: int) -> np.ndarray:
    x = np.where(np.isfinite(x), x, 0.0)
    c = np.concatenate([[0.0], np.cumsum(x * x)])
    k = np.arange(1, x.size + 1)
    lo = np.maximum(0, k - n)
    return np.asarray(np.sqrt((c[k] - c[lo]) / (k - lo)))


def plot_tracking(path: Path, host: HybridHost) -> Path:
    k = host.k
    t = np.arange(k) * host.dt_s
    rec = host.record[:, :k] * np.array([[1e3], [1e3], [1e3], [1], [1], [1]])
    fig = new_figure(10.0, 7.5)
    axes = fig.subplots(3, 1)
    ax = axes[0]
    ax.plot(t, rec[0], lw=0.8, label="target (the car's damper stroke)")
    ax.plot(t, rec[2], lw=0.8, label="measured on the rig")
    decorate(ax, "time [s]", "stroke [mm]")
    sl = host.road.evaluated
    mid = (sl.start + min(sl.stop, k)) // 2
    n = int(CLOSE_UP_S / host.dt_s)
    z = slice(max(0, mid - n // 2), min(k, mid + n // 2))
    ax = axes[1]
    ax.plot(t[z], rec[0, z], lw=1.2, label="target")
    ax.plot(t[z], rec[1, z], lw=0.8, ls="--", label="demand sent")
    ax.plot(t[z], rec[2, z], lw=1.0, label="measured")
    ax.set_title(f"close-up, {CLOSE_UP_S:g} s", fontsize=9)
    decorate(ax, "time [s]", "stroke [mm]")
    ax = axes[2]
    ax.plot(t, rec[2] - rec[0], lw=0.6, color="tab:red", label="measured − target")
    decorate(ax, "time [s]", "error [mm]")
    fig.suptitle(f"damper in the loop: stroke tracking ({host.compensator_params.mode} "
                 "compensation)")
    return save(fig, path)


def plot_force(path: Path, host: HybridHost) -> Path:
    k = host.k
    t = np.arange(k) * host.dt_s
    rec = host.record[:, :k]
    fig = new_figure(10.0, 6.0)
    axes = fig.subplots(2, 1, sharex=True)
    ax = axes[0]
    ax.plot(t, rec[3] / 1e3, lw=0.7, label="measured (the damper on the rig)")
    ax.plot(t, rec[4] / 1e3, lw=0.7, ls="--", label="twin (the model on the measured motion)")
    decorate(ax, "time [s]", "force [kN]")
    ax = axes[1]
    residual = rec[3] - rec[4]
    ax.plot(t, residual, lw=0.5, color="0.6", label="residual, measured − twin")
    window = int(RUNNING_RMS_S / host.dt_s)
    ax.plot(t, _running_rms(residual, window), lw=1.5, color="tab:red",
            label=f"its r.m.s. over {RUNNING_RMS_S:g} s")
    if host.online.enabled:
        ax.plot(t, _running_rms(rec[3] - host.twin_raw[:k], window), lw=1.2,
                color="tab:purple", ls=":",
                label="the same, the twin as it came (no correction during the ride)")
    decorate(ax, "time [s]", "force [N]")
    fig.suptitle("damper in the loop: measured force and the twin's")
    return save(fig, path)


def plot_transfer(path: Path, host: HybridHost) -> Path | None:
    if host.transfer is None:
        return None
    u, x = host.identification
    t = np.arange(u.size) * host.dt_s
    fig = new_figure(10.0, 4.0)
    ax = fig.subplots()
    ax.plot(t, u * 1e3, lw=0.8, label="demand")
    ax.plot(t, x * 1e3, lw=0.8, label="measured")
    ax.plot(t, response(u, host.dt_s, host.transfer) * 1e3, lw=0.8, ls="--",
            label="fitted transfer model")
    left_out = ~host.usable
    if left_out.any():
        ax.fill_between(t, 0.0, 1.0, where=left_out, transform=ax.get_xaxis_transform(),
                        color="0.85", step="post", label="left out (stall)")
    est = host.transfer
    ax.set_title(f"delay {est.delay_s * 1e3:.2f} ms, servo {est.bandwidth_hz:.1f} Hz, "
                 f"damping {est.damping:.2f}, gain {est.gain:.3f}, fit "
                 f"{est.fit_nrms:.1%} r.m.s.", fontsize=9)
    decorate(ax, "time [s]", "stroke [mm]")
    fig.suptitle("transfer-system identification before the ride")
    return save(fig, path)


def _fmt(value: Any, fmt: str) -> str:
    return "–" if value is None or (isinstance(value, float) and not math.isfinite(value)) \
        else format(value, fmt)


def write_report(out: Path, host: HybridHost, doc: dict[str, Any]) -> list[Path]:
    """The plots and ``report.md`` under ``out``; returns the files written."""
    files = [plot_tracking(out / "hybrid_tracking.png", host),
             plot_force(out / "hybrid_force.png", host)]
    transfer = plot_transfer(out / "hybrid_transfer.png", host)
    if transfer is not None:
        files.append(transfer)
    lines = ["# Damper in the loop", "",
             f"Status: **{doc['status']}**" + (f" — {doc['reason']}" if doc["reason"] else ""),
             ""]
    tr = doc.get("tracking")
    if tr:
        lines += ["## Tracking", "", "| criterion | value |", "|---|---|",
                  f"| NRMS error | {_fmt(tr['nrms'] * 100, '.2f')} % |",
                  f"| peak error | {_fmt(tr['peak_error_m'] * 1e3, '.3f')} mm |",
                  f"| residual delay | {_fmt(tr['delay_ms'], '.3f')} ms |",
                  f"| rig delay as followed | "
                  f"{_fmt(doc.get('tracking_delay_estimate_ms'), '.3f')} ms |", ""]
    lines += ["![tracking](hybrid_tracking.png)", ""]
    if doc.get("ride"):
        lines += ["## Ride against the all-numerical reference", "",
                  "| metric | hybrid | reference | difference |", "|---|---|---|---|"]
        for key, value in doc["ride"].items():
            ref = doc["reference"][key]
            lines.append(f"| {key} | {value:.5g} | {ref:.5g} | "
                         f"{(value / ref - 1) * 100:+.2f} % |")
        lines.append("")
    twin = doc["twin"]
    lines += ["## Twin", "",
              f"Residual r.m.s. {_fmt(twin['residual_rms_n'], '.1f')} N over the run; "
              f"{_fmt(twin['residual_rms_first_n'], '.1f')} N over the ride's first "
              f"{TWIN_WINDOW_S:g} s, "
              f"{_fmt(twin['residual_rms_last_n'], '.1f')} N over its last.", "",
              "![force](hybrid_force.png)", ""]
    online = twin.get("online")
    if online is not None and online["enabled"]:
        without = online["without"]
        lines += ["The twin kept learning during the ride (a bounded correction of its "
                  "force map, `learn.online`), and each force above is its prediction "
                  "before its own sample taught it. Without the correction, as the twin "
                  f"came to the ride: {_fmt(without['residual_rms_n'], '.1f')} N over the "
                  f"run, {_fmt(without['residual_rms_first_n'], '.1f')} N over the first "
                  f"{TWIN_WINDOW_S:g} s, {_fmt(without['residual_rms_last_n'], '.1f')} N "
                  "over the last. The correction at the end:", "",
                  "| term | value |", "|---|---|"]
        lines += [f"| {name} | {_fmt(value, '.4g')} |" for name, value in online["terms"].items()]
        lines.append("")
    learned = doc.get("twin_learning")
    if learned is not None:
        lines += ["The twin learned the specimen before the ride (`--learn`) from the files "
                  "below; the ride used `" + Path(learned["params_file"]).name + "`. Its "
                  "residual on them, before and after:", "",
                  "| file | before [N] | after [N] |", "|---|---|---|"]
        for name, after in learned["residual_after"].items():
            lines.append(f"| {name} | {_fmt(learned['residual_before'][name]['rms_n'], '.1f')} "
                         f"| {_fmt(after['rms_n'], '.1f')} |")
        lines.append("")
    if "transfer" in doc:
        st = doc["stability"]
        lines += ["## Transfer system and stability", "",
                  f"Force-path loop gain {st['force_path_gain']:.2f} at "
                  f"{_fmt(st['at_hz'], '.1f')} Hz (damper slope "
                  f"{st['damper_slope_ns_m']:.0f} N s/m): "
                  + ("below one, stable by the small-gain theorem."
                     if st["force_path_gain"] < 1 else "**not below one**.")
                  + (f" With the twin's slope as the online correction left it "
                     f"({_fmt(st['online']['damper_slope_ns_m'], '.0f')} N s/m), the margin "
                     f"is {_fmt(st['online']['small_gain_margin'], '.2f')}."
                     if "online" in st and st["force_path_gain"] > 0 else ""), "",
                  "![transfer](hybrid_transfer.png)", ""]
    files.append(write_text(out / "report.md", "\n".join(lines) + "\n"))
    return files
