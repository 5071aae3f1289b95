"""Report of a closed-loop HIL run (``damper-hil demo``): plots and a summary from the
recorded bag, the ride node's metrics and the emulator's loop record.  No rclpy."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.dyno.plots import decorate, new_figure, save
from damper_emulator.outputs import write_text
from damper_emulator.realtime.core import Status
from damper_emulator.realtime.loop import load_record
from damper_emulator.recording import Recording
from ride_sim.loop_delay import MAX_PHASE_LAG


def plot_ride(path: Path, rec: Recording, sprung_mass_kg: float) -> Path:
    """Road, body and wheel heights, body acceleration, dynamic tyre load and damper force
    against time."""
    r = rec.ride
    t = (r.log_ns - r.log_ns[0]) * 1e-9
    fig = new_figure(10, 9)
    axes = fig.subplots(4, 1, sharex=True)
    axes[0].plot(t, r.road_m * 1e3, lw=0.6, label="road")
    axes[0].plot(t, r.wheel_m * 1e3, lw=0.6, label="wheel")
    axes[0].plot(t, r.body_m * 1e3, lw=0.9, label="body")
    decorate(axes[0], "", "height [mm]")
    axes[1].plot(t, r.body_force_n / sprung_mass_kg, lw=0.6)
    decorate(axes[1], "", "body accel. [m/s²]", legend=False)
    axes[2].plot(t, r.dtl_n / 1e3, lw=0.6)
    decorate(axes[2], "", "dynamic tyre load [kN]", legend=False)
    axes[3].plot(t, r.damper_force_n / 1e3, lw=0.6)
    decorate(axes[3], "time since the first sample [s]", "damper force [kN]", legend=False)
    fig.suptitle("Closed loop over ROS 2: quarter car on the minor road, emulated damper")
    return save(fig, path)


def plot_damper(path: Path, rec: Recording) -> Path:
    """The emulated damper's force against velocity and stroke (model outputs only)."""
    f = rec.force
    ok = (f.status & int(Status.NO_INPUT | Status.TIMEOUT)) == 0
    fig = new_figure(10, 4.5)
    ax1, ax2 = fig.subplots(1, 2)
    ax1.plot(f.velocity_m_s[ok], f.force_n[ok] / 1e3, lw=0.3)
    decorate(ax1, "damper velocity [m/s] (extension +)", "force [kN] (rebound +)",
             legend=False)
    ax2.plot(f.stroke_m[ok] * 1e3, f.force_n[ok] / 1e3, lw=0.3)
    decorate(ax2, "stroke [mm] (extension +)", "force [kN] (rebound +)", legend=False)
    fig.suptitle(f"/damper/force: {int(ok.sum())} model outputs "
                 f"({int((~ok).sum())} fault outputs left out)")
    return save(fig, path)


def plot_control(path: Path, rec: Recording) -> Path | None:
    """The valve command against time, with the body velocity the controller saw."""
    if rec.valve_command is None:
        return None
    log_ns, command = rec.valve_command
    t0 = rec.ride.log_ns[0] if rec.ride is not None else log_ns[0]
    fig = new_figure(10, 5)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.step((log_ns - t0) * 1e-9, command, where="post", lw=0.6)
    ax1.set_ylim(-0.05, 1.05)
    decorate(ax1, "", "valve command\n0 comfort … 1 sport", legend=False)
    if rec.ride is not None and rec.ride.body_rate_m_s is not None:
        r = rec.ride
        ax2.plot((r.log_ns - t0) * 1e-9, r.body_rate_m_s, lw=0.6)
    decorate(ax2, "time since the first ride sample [s]", "body velocity [m/s]", legend=False)
    fig.suptitle(f"/damper/valve_command over CAN: {command.size} commands, mean "
                 f"{command.mean():.2f}")
    return save(fig, path)


def load_loop_record(stats_file: Path):
    """``(arrays, summary)`` of the emulator's loop record (``emulator.stats_file``), or None
    when there is none or it is empty."""
    if not stats_file.is_file():
        return None
    z, s = load_record(stats_file)
    return (z, s) if z["periods_ns"].size else None


def loop_summary(record) -> dict[str, Any] | None:
    """Period statistics of a loop record (:func:`load_loop_record`; None: none)."""
    if record is None:
        return None
    z, s = record
    doc = {"ticks": s.ticks, "achieved_rate_hz": s.achieved_rate_hz,
           "period_p50_us": s.period_p50_us, "period_p99_us": s.period_p99_us,
           "period_max_us": s.period_max_us, "period_error_p99_us": s.error_p99_us,
           "wake_latency_p99_us": s.wake_p99_us, "tick_work_p99_us": s.work_p99_us,
           "overruns": s.overruns, "skipped": s.skipped, "realtime": str(z["realtime"])}
    for key in ("warm_up_s", "compiled_after_ready"):
        if key in z:
            doc[key] = z[key].item()
    first = int(z["first_input_tick"]) if "first_input_tick" in z else -1
    if first >= 0:
        # the ring holds the latest periods: period k lies between ticks k and k + 1
        periods = z["periods_ns"]
        start = first - (int(z["ticks"]) - 1 - periods.size)
        after = periods[max(0, start):]
        if after.size:
            err = np.abs(after - int(z["period_ns"])) / 1e3
            doc["after_first_input"] = {
                "periods": int(after.size),
                "period_max_us": float(after.max() / 1e3),
                "period_error_p99_us": float(np.percentile(err, 99)),
                "overruns": int((after > 2 * int(z["period_ns"])).sum())}
    return doc


def plot_loop(path: Path, record) -> Path | None:
    """The loop periods of a loop record (:func:`load_loop_record`) against time and their
    histogram; None when there is no record."""
    if record is None:
        return None
    z, _ = record
    p = z["periods_ns"] / 1e3
    fig = new_figure(10, 4)
    ax1, ax2 = fig.subplots(1, 2)
    ax1.plot(np.arange(p.size) / (1e6 / p.mean()), p, lw=0.4)
    decorate(ax1, "time [s]", "loop period [µs]", legend=False)
    ax2.hist(p, bins=np.linspace(0, 3 * float(z["period_ns"]) / 1e3, 121), log=True)
    decorate(ax2, "loop period [µs]", "ticks", legend=False)
    fig.suptitle(f"Emulator loop: {p.size} periods, p99 {np.percentile(p, 99):.0f} µs, "
                 f"max {p.max():.0f} µs, {int(z['overruns'])} overruns (> 2 periods)")
    return save(fig, path)


def _control_lines(summary: dict[str, Any]) -> list[str]:
    """The control-over-CAN rows of the report (none when no bridge ran)."""
    bridge = summary.get("bridge_diagnostics")
    valve = summary.get("valve_command")
    if not bridge and not valve:
        return []
    lines = ["| control over CAN | value |", "|---|---|",
             f"| control | {summary.get('control', '')} on {summary.get('can_bus', '')} |"]
    if valve:
        lines.append(f"| /damper/valve_command | {valve['count']} commands, mean "
                     f"{valve['mean']:.3f}, range {valve['min']:.3f} … {valve['max']:.3f} |")
    if bridge:
        lines.append(f"| bridge | {bridge.get('message', '')}: {bridge.get('commands_in')} "
                     f"VALVE_COMMAND in, {bridge.get('motion_out')} VEHICLE_MOTION and "
                     f"{bridge.get('forces_out')} DAMPER_FORCE out; dropped (length / "
                     f"checksum / counter) {bridge.get('dropped_length')} / "
                     f"{bridge.get('dropped_checksum')} / {bridge.get('dropped_counter')}, "
                     f"lost {bridge.get('lost_frames')} |")
    return [*lines, ""]


def _delay_line(delay: dict[str, Any] | None) -> str:
    """The report's row of the ride's loop delay (:mod:`ride_sim.loop_delay`)."""
    if not delay:
        return "| loop delay (state to force applied) | not measured (lockstep clock) |"
    verdict = ("within" if delay["within_bound"] else
               f"**over at {delay['over_bound']} of {delay['samples']} samples**:")
    return (f"| loop delay (state to force applied) p50 / p99 / max | "
            f"{delay['p50_ms']:.0f} / {delay['p99_ms']:.0f} / {delay['max_ms']:.0f} ms, "
            f"{verdict} the bound {delay['bound_ms']:.1f} ms "
            f"({math.degrees(MAX_PHASE_LAG):.0f}° at the wheel hop) |")


def write_report(out: Path, rec: Recording, ride_doc: dict[str, Any],
                 stats_file: Path, sprung_mass_kg: float, extra: dict[str, Any],
                 mf4: bool = False) -> dict[str, Any]:
    """Plots, ``demo.json`` and ``report.md`` under ``out`` (and with ``mf4`` the
    recording's time series as ``demo.mf4``); returns the summary."""
    files = []
    if mf4:
        from damper_emulator.recording_mdf import write_recording_mdf

        files.append(write_recording_mdf(rec, out / "demo.mf4", "damper-hil demo: "
                                         f"{extra.get('mode', 'the HIL demo')}").name)
    if rec.ride is not None:
        files.append(plot_ride(out / "ride.png", rec, sprung_mass_kg).name)
    if rec.force is not None:
        files.append(plot_damper(out / "damper.png", rec).name)
    control_png = plot_control(out / "control.png", rec)
    if control_png is not None:
        files.append(control_png.name)
    loop_record = load_loop_record(stats_file)
    loop_png = plot_loop(out / "loop.png", loop_record)
    if loop_png is not None:
        files.append(loop_png.name)
    faults = faults_in_ride = 0
    if rec.force is not None:
        fault = (rec.force.status & int(Status.NO_INPUT | Status.TIMEOUT)) != 0
        faults = int(fault.sum())
        fed = ~((rec.force.status & int(Status.NO_INPUT)) != 0)
        if fed.any() and rec.state is not None and rec.state.log_ns.size:
            # from the first output made from an input to the last input (the ride's end:
            # the timeouts after it are the ride stopping, not the loop failing)
            t = rec.force.log_ns
            ride = (t >= t[np.argmax(fed)]) & (t <= rec.state.log_ns[-1])
            faults_in_ride = int((fault & ride).sum())
    loop_doc = loop_summary(loop_record)
    summary = {
        **extra,
        "bag": str(rec.path),
        "topics": rec.counts,
        "fault_outputs": faults,
        "fault_outputs_after_first_input": faults_in_ride,
        "kernels_compiled_after_ready": (loop_doc or {}).get("compiled_after_ready"),
        "ride": ride_doc,
        "emulator_loop": loop_doc,
        "emulator_diagnostics": rec.last_diagnostics,
        "bridge_diagnostics": rec.bridge_diagnostics or None,
        "valve_command": None if rec.valve_command is None else {
            "count": int(rec.valve_command[1].size),
            "mean": float(rec.valve_command[1].mean()),
            "min": float(rec.valve_command[1].min()),
            "max": float(rec.valve_command[1].max())},
        "files": [*files, "demo.json", "report.md"],
    }
    write_text(out / "demo.json", json.dumps(summary, indent=2) + "\n")
    m = ride_doc.get("metrics", {})
    loop = summary["emulator_loop"] or {}
    after = loop.get("after_first_input") or {}
    lines = [
        "# Closed-loop HIL demo",
        "",
        f"Quarter car (config/quarter_car.yaml) on the minor road at "
        f"{ride_doc.get('speed_m_s', float('nan')):g} m/s for "
        f"{ride_doc.get('duration_s', float('nan')):g} s, clock `{ride_doc.get('clock')}`, "
        f"against the emulated 'sport' damper over ROS 2; recorded to `{rec.path.name}/`.",
        "",
        "| ride metric | value |",
        "|---|---|",
        f"| SWS r.m.s. | {m.get('sws_rms', float('nan')) * 1e3:.2f} mm |",
        f"| weighted body acceleration (Wk) r.m.s. | {m.get('accel_w_rms', float('nan')):.3f} "
        f"m/s² |",
        f"| dynamic tyre load r.m.s. | {m.get('dtl_rms', float('nan')):.0f} N |",
        f"| real-time factor of the ride loop | {ride_doc.get('real_time_factor')} |",
        _delay_line(ride_doc.get("loop_delay")),
        "",
        "| emulator loop | value |",
        "|---|---|",
        f"| achieved rate | {loop.get('achieved_rate_hz', float('nan')):.2f} Hz |",
        f"| period p50 / p99 / max | {loop.get('period_p50_us', float('nan')):.0f} / "
        f"{loop.get('period_p99_us', float('nan')):.0f} / "
        f"{loop.get('period_max_us', float('nan')):.0f} µs |",
        f"| p99 period error | {loop.get('period_error_p99_us', float('nan')):.0f} µs |",
        f"| wake-up latency p99 / tick work p99 | "
        f"{loop.get('wake_latency_p99_us', float('nan')):.0f} / "
        f"{loop.get('tick_work_p99_us', float('nan')):.0f} µs |",
        f"| overruns (> 2 periods) | {loop.get('overruns')} |",
        f"| real-time settings | {loop.get('realtime', '')} |",
        f"| fault outputs (no input yet / stale input) | {faults} |",
        f"| fault outputs from the first input to the ride's end | {faults_in_ride} |",
        f"| from the first input on: period max / p99 error / overruns | "
        f"{after.get('period_max_us', float('nan')):.0f} / "
        f"{after.get('period_error_p99_us', float('nan')):.0f} µs / "
        f"{after.get('overruns')} |",
        f"| model warm-up before 'active' / kernels compiled after | "
        f"{loop.get('warm_up_s', float('nan')):.2f} s / "
        f"{loop.get('compiled_after_ready')} |",
        "",
        *_control_lines(summary),
        "| topic | messages |",
        "|---|---|",
        *[f"| `{k}` | {v} |" for k, v in sorted(rec.counts.items())],
        "",
        *[f"![{f}]({f})" for f in files],
        "",
    ]
    write_text(out / "report.md", "\n".join(lines))
    return summary
