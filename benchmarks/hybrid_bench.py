#!/usr/bin/env python3
"""Benchmark of ``damper-hil hybrid`` against ``damper-hil virtual-rig``; prints markdown
tables.

The rig: 4 ms transport delay, a 40 Hz servo with damping 0.7, the virtual rig's default
specimen (``config/prototype.yaml``: a sport prototype that the sport twin misses by about
40 % r.m.s. of force); 20 s of an ISO 8608 class C road at 20 m/s.  Both commands run as
processes on a ``udp_multicast`` bus of their own, in turn (so that on a 2-core machine
they do not compete for the cores):

1. on the same rig, ``--repeats`` times each: **the twin learned** (``--learn``, the
   headline), the sport twin as it is, **uncompensated**, the host sleeping until each
   feedback (no polling), and for reference a specimen that *is* the twin
   (``--params config/sport.yaml``): tracking NRMS, peak error, residual delay, the
   ride's r.m.s. values against the all-numerical reference, the twin's residual (over
   the ride, over its last 2 s, and over its last 2 s without the online correction;
   each over the measured force's r.m.s. there), the host's response time (feedback arrival → its
   command sent) p50/p99/max;
2. **robustness**: the delay doubled 12 s after the host's first command, some 8 s into
   the ride (tracking NRMS over 2 s before the change, the first 0.5 s after it and the
   2 s after that, against the same stretch of a ride on a rig at 8 ms from its start);
   the feedback cut (Enable clear after the last valid feedback, at the rig); a corrupted
   feedback frame in every 100; 30 ms
   uncompensated (stopped by the detector before any limit?);
3. **offline**: the same host and rig on a simulated timeline (no bus, no clock): what the
   compensator reaches without jitter;
4. **twin** (``--twin-chain``): a specimen that fades with temperature (a
   ``viscosity_temperature`` extension the twin lacks); ``dyno`` quasi-static and chirp on
   the rig, ``identify`` on them, ``hybrid`` with the identified twin, ``diagnose`` with the
   ride as held-out data: the twin's residual over the ride and the diagnosed family.

Usage: ``python benchmarks/hybrid_bench.py [--repeats 2] [--duration 20] [--twin-chain]``
(``make bench`` runs it through ``benchmarks/run_all.py``, which writes its tables into
docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from machine import cpu_name

from damper_emulator.model.compressible import DamperModel
from ride_sim.hybrid.criteria import TWIN_WINDOW_S
from ride_sim.hybrid.host import RIDE_KEYS, HybridHost
from ride_sim.hybrid.offline import run_offline
from ride_sim.hybrid.params import (
    ActuatorParams,
    CompensatorParams,
    HybridRunParams,
    RigParams,
    SafetyParams,
)
from ride_sim.hybrid.rig import VirtualRig
from ride_sim.params import load_quarter_car

CLI = [sys.executable, "-m", "damper_hil.cli"]
#: the two loops on CPUs of their own where there are two
PIN_HOST, PIN_RIG = (["--cpu", "0"], ["--cpu", "1"]) if (os.cpu_count() or 1) >= 2 \
    else ([], [])


def channel(n: int) -> str:
    pid = os.getpid()
    return f"[ff11::d7:{n:x}:{pid & 0xFFFF:x}]:{22000 + (pid % 300) * 10 + n}"


#: the pinning of the run (``--unpinned`` clears it): (host's, rig's) arguments
PINS = [PIN_HOST, PIN_RIG]


def run_pair(tmp: Path, n: int, rig_args, hybrid_args):
    """``virtual-rig RIG_ARGS`` and ``hybrid HYBRID_ARGS`` on bus ``n``, pinned; returns the
    hybrid process, its ``hybrid.json``, the rig's statistics (``rig.json``; ``{}`` when a
    file is missing) and the hybrid's wall time [s]."""
    pin_host, pin_rig = PINS
    ch = channel(n)
    bus = ["--can-interface", "udp_multicast", "--can-channel", ch]
    rig = subprocess.Popen([*CLI, "virtual-rig", *bus, "--json", str(tmp / "rig.json"),
                            *pin_rig, *rig_args], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                           text=True)
    t0 = time.perf_counter()
    proc = subprocess.run([*CLI, "hybrid", "--out", str(tmp / "out"), *bus, *pin_host,
                           *hybrid_args],
                          capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    rig.send_signal(2)
    rig.communicate(timeout=30)
    doc, rig_doc = (json.loads(path.read_text()) if path.exists() else {}
                    for path in (tmp / "out" / "hybrid.json", tmp / "rig.json"))
    return proc, doc, rig_doc, elapsed


def twin_cell(doc: dict, case: Path) -> str:
    """The twin's residual [N] and its share of the measured force's r.m.s.: over the ride,
    over its last 2 s (of the force there), and over its last 2 s without the online
    correction (the twin as it came to the ride)."""
    twin = doc.get("twin") or {}
    csv = case / "out" / "hybrid.csv"
    if "residual_rms_n" not in twin or not csv.exists():
        return "–"
    rows = np.genfromtxt(csv, delimiter=",", names=True)
    window = int(round(TWIN_WINDOW_S / np.median(np.diff(rows["time"]))))
    force = rows["force_measured"][np.isfinite(rows["force_measured"])]
    whole, last = np.sqrt(np.mean(force ** 2)), np.sqrt(np.mean(force[-window:] ** 2))
    without = (twin.get("online") or {}).get("without", {}).get("residual_rms_last_n")
    cell = (f"{twin['residual_rms_n']:.0f} ({twin['residual_rms_n'] / whole * 100:.1f} %); "
            f"{twin['residual_rms_last_n']:.0f} ({twin['residual_rms_last_n'] / last * 100:.1f} %)")
    if without is not None:
        cell += f"; {without:.0f} ({without / last * 100:.1f} %)"
    return cell


#: The delay-change case is scored over this long before the change and after it [s] ...
AROUND_S = 2.0
#: ... the second stretch after the tracker's first this long [s].
SETTLE_S = 0.5


def around(out: Path, changed_ns: int | None, at_s: float | None = None
           ) -> tuple[float, float, float, float]:
    """The tracking's NRMS over :data:`AROUND_S` before a moment of the ride, over the
    :data:`SETTLE_S` after it and over :data:`AROUND_S` after that, and the moment [s into
    the ride]: the rig's ``changed_ns`` on the monotonic clock, or ``at_s``."""
    d = np.genfromtxt(out / "hybrid.csv", delimiter=",", names=True)
    t = d["time"]
    if changed_ns is not None:
        stamped = d["t_monotonic_ns"] > 0
        at_s = float(np.interp(changed_ns, d["t_monotonic_ns"][stamped].astype(float),
                               t[stamped]))
    assert at_s is not None

    def nrms(lo: float, hi: float) -> float:
        sl = (t >= lo) & (t < hi)
        x, e = d["stroke_target"][sl], d["stroke_measured"][sl] - d["stroke_target"][sl]
        return float(np.sqrt(np.nanmean(e ** 2) / np.nanmean(x ** 2)))

    return (nrms(at_s - AROUND_S, at_s), nrms(at_s, at_s + SETTLE_S),
            nrms(at_s + SETTLE_S, at_s + SETTLE_S + AROUND_S), at_s)


def fmt(x, spec=".2f"):
    return "–" if x is None else format(x, spec)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--twin-chain", action="store_true")
    ap.add_argument("--twin-only", action="store_true", help="only the twin chain")
    ap.add_argument("--unpinned", action="store_true",
                    help="neither loop pinned to a CPU (the README's command as it is)")
    ap.add_argument("--headline", action="store_true",
                    help="only the learned twin's rides (no other case, no robustness)")
    run(ap.parse_args())


def run(args: argparse.Namespace) -> None:
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    root = Path(tempfile.mkdtemp(prefix="hybrid_bench_"))
    if args.twin_only:
        twin_chain(root / "twin", args.duration)
        return
    if args.unpinned:
        PINS[:] = [[], []]
    pin_host, pin_rig = PINS
    dur = ["--duration", f"{args.duration:g}", "--road-class", "C", "--speed", "20"]
    print(f"# Damper in the loop: `damper-hil hybrid` against `virtual-rig` — {cpu_name()}, "
          f"{os.cpu_count()} CPUs, Python {sys.version.split()[0]}\n")
    print(f"Rig: 4 ms transport delay, 40 Hz servo, damping 0.7, the sport prototype "
          f"(config/prototype.yaml) unless said; "
          f"{args.duration:g} s of ISO 8608 class C at 20 m/s; udp_multicast; host loop "
          f"{' '.join(pin_host) or 'unpinned'}, rig {' '.join(pin_rig) or 'unpinned'}.\n")
    # 1. compensated and uncompensated, in turn
    rows = []
    n = 0
    # the host sleeping until each feedback comes (no polling): what polling buys
    sleeping = root / "sleeping.yaml"
    sleeping.write_text("/**:\n  ros__parameters:\n    hybrid:\n      poll_before_s: 0.0\n",
                        encoding="utf-8")
    sport = str(Path(__file__).resolve().parents[1] / "config" / "sport.yaml")
    # (label, rig's arguments, hybrid's)
    cases = (("model, learned twin", [], ["--compensation", "model", "--learn"]),
             ("model, sport twin", [], ["--compensation", "model"]),
             ("none", [], ["--compensation", "none"]),
             ("model, learned, no polling", [],
              ["--compensation", "model", "--learn", "--config", str(sleeping)]),
             ("model, specimen = twin (reference)", ["--params", sport],
              ["--compensation", "model"]))
    if args.headline:
        cases = cases[:1]
    for r in range(args.repeats):
        for i, (mode, rig_args, hybrid_args) in enumerate(cases):
            n += 1
            tmp = root / f"case{i}-{r}"
            tmp.mkdir()
            proc, doc, _, elapsed = run_pair(tmp, n, rig_args, [*dur, *hybrid_args])
            if not doc:
                print(f"{mode} run {r}: failed: {proc.stderr.strip().splitlines()[-1:]}")
                continue
            rows.append((mode, r, proc.returncode, doc, elapsed))
    print("## On the same rig: the twin learned, as it is, uncompensated\n")
    print("| case | run | exit | NRMS [%] | peak [mm] | residual delay [ms] | "
          "rig delay followed [ms] | SWS / ref | Wk accel / ref | DTL / ref | "
          "twin residual [N] (of the force): ride; last 2 s; last 2 s as it came | "
          "response p50 / p99 / max [µs] | of it, read p50 / p99 [µs] | force-path gain |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for mode, r, rc, doc, _ in rows:
        tr = doc.get("tracking") or {}
        rr = doc.get("ride_vs_reference") or {}
        link = doc.get("link", {})
        st = doc.get("stability", {})
        print(f"| {mode} | {r + 1} | {rc} | {fmt(tr.get('nrms', 0) * 100)} | "
              f"{fmt(tr.get('peak_error_m', 0) * 1e3)} | {fmt(tr.get('delay_ms'))} | "
              f"{fmt(doc.get('tracking_delay_estimate_ms'))} | "
              + " | ".join(f"{rr[k] * 100:+.2f} %" if k in rr else "–" for k in RIDE_KEYS)
              + f" | {twin_cell(doc, root / f'case{[c[0] for c in cases].index(mode)}-{r}')}"
              + f" | {fmt(link.get('response_p50_us'), '.0f')} / "
              f"{fmt(link.get('response_p99_us'), '.0f')} / "
              f"{fmt(link.get('response_max_us'), '.0f')} | "
              f"{fmt(link.get('read_p50_us'), '.0f')} / {fmt(link.get('read_p99_us'), '.0f')} | "
              f"{fmt(st.get('force_path_gain'))} |")
    head, polled = "model, learned twin", "model, learned, no polling"
    comp = [d["tracking"]["nrms"] for m, _, _, d, _ in rows if m == head and d.get("tracking")]
    none = [d["tracking"]["nrms"] for m, _, _, d, _ in rows if m == "none" and d.get("tracking")]
    p99 = {label: [d["link"]["response_p99_us"] for m, _, _, d, _ in rows
                   if m == label and d.get("link", {}).get("response_p99_us") is not None]
           for label, *_ in cases}
    if p99[head] and p99[polled]:
        print(f"\nResponse p99 compensated, polling: {statistics.mean(p99[head]):.0f} µs "
              f"(runs {', '.join(f'{x:.0f}' for x in p99[head])}); sleeping until the "
              f"frame comes: {statistics.mean(p99[polled]):.0f} µs: ratio "
              f"{statistics.mean(p99[polled]) / statistics.mean(p99[head]):.2f}.")
    if comp and none:
        print(f"\nNRMS compensated with the learned twin {statistics.mean(comp) * 100:.2f} % "
              f"(spread "
              f"{(max(comp) - min(comp)) * 100:.2f}; runs "
              f"{', '.join(f'{x * 100:.2f}' for x in comp)}), uncompensated "
              f"{statistics.mean(none) * 100:.2f} %: ratio "
              f"{statistics.mean(none) / statistics.mean(comp):.0f}×.\n")
    if args.headline:
        done = [d for m, _, rc, d, _ in rows if m == head and rc == 0]
        print(f"\nLearned twin, {'unpinned' if args.unpinned else 'pinned'}: {len(done)} of "
              f"{args.repeats} rides completed, NRMS "
              + ", ".join(f"{d['tracking']['nrms'] * 100:.2f}" for d in done) + " %.")
        return
    # 2. robustness
    print("## Robustness\n")
    print("| case | exit | reason | measure |")
    print("|---|---|---|---|")
    n += 1
    tmp = root / "doubled"
    tmp.mkdir()
    proc, doc, rig_doc, _ = run_pair(tmp, n, ["--delay-change-at", "12",
                                               "--delay-change-to-ms", "8"], dur)
    changed_ns = rig_doc.get("delay_changed_ns")
    n += 1
    ref = root / "eight"
    ref.mkdir()
    _, ref_doc, _, _ = run_pair(ref, n, ["--delay-ms", "8"], dur)
    if not doc or changed_ns is None or proc.returncode != 0:
        # a ride stopped (by the safety layer) before or after the change: say so
        print(f"| delay 4 → 8 ms mid-ride, adapted | {proc.returncode} | "
              f"{doc.get('reason') or '–'} | the change "
              f"{'came' if changed_ns is not None else 'did not come'}; not scored |")
    else:
        before, first, after, at_s = around(tmp / "out", changed_ns)
        # the same stretch of the ride on a rig at 8 ms from its start, identified so
        _, _, same, _ = around(ref / "out", None, at_s) if ref_doc else (0, 0, math.nan, 0)
        print(f"| delay 4 → 8 ms mid-ride, adapted | {proc.returncode} | "
              f"{doc.get('reason') or '–'} | at {at_s:.1f} s into the ride: NRMS "
              f"{before * 100:.1f} % over the {AROUND_S:g} s before, {first * 100:.1f} % "
              f"over the first {SETTLE_S:g} s after, {after * 100:.1f} % over the "
              f"{AROUND_S:g} s after that (a rig at 8 ms from its start, the same "
              f"stretch: {same * 100:.1f} %); rig delay followed at the end "
              f"{doc.get('tracking_delay_estimate_ms', 0):.2f} ms |")
    n += 1
    tmp = root / "cut"
    tmp.mkdir()
    proc, doc, rig_doc, _ = run_pair(tmp, n, ["--feedback-stop-at", "10"], dur)
    # at the rig (a real-time process that reads every command): its last feedback sent,
    # the first command with Enable clear received
    sent, cleared = rig_doc.get("last_feedback_ns"), rig_doc.get("enable_cleared_ns")
    print(f"| feedback cut | {proc.returncode} | {doc.get('reason', '–')} | " + (
        f"Enable clear {(cleared - sent) * 1e-6:.1f} ms after the last feedback, at the rig"
        if sent is not None and cleared is not None
        else "no command with Enable clear after the last feedback") + " |")
    n += 1
    tmp = root / "corrupt"
    tmp.mkdir()
    proc, doc, _, _ = run_pair(tmp, n, ["--corrupt-every", "100"], dur)
    link = doc.get("link", {})
    print(f"| a corrupted feedback frame in 100 | {proc.returncode} | "
          f"{doc.get('reason') or '–'} | {link.get('dropped_checksum')} dropped of "
          f"{link.get('feedback', 0) + link.get('dropped_checksum', 0)}; NRMS "
          f"{doc['tracking']['nrms'] * 100:.2f} % |")
    n += 1
    tmp = root / "unstable"
    tmp.mkdir()
    proc, doc, _, _ = run_pair(tmp, n, ["--delay-ms", "30"], [*dur, "--compensation", "none"])
    d = np.genfromtxt(tmp / "out" / "hybrid.csv", delimiter=",", skip_header=1)
    lim = SafetyParams()
    print(f"| 30 ms, uncompensated | {proc.returncode} | {doc.get('reason', '–')} | "
          f"max stroke {np.nanmax(np.abs(d[:, 4])) * 1e3:.1f} mm (limit "
          f"{lim.stroke_limit_m * 1e3:g}), max force {np.nanmax(np.abs(d[:, 5])):.0f} N "
          f"(limit {lim.force_limit_n:g}) |")
    # 3. offline
    print("\n## Offline (the same cores on a simulated timeline, no bus)\n")
    print("| compensation | NRMS [%] | SWS / ref | Wk accel / ref | DTL / ref | time [s] |")
    print("|---|---|---|---|---|---|")
    model = DamperModel()
    for mode in ("model", "none"):
        t0 = time.perf_counter()
        host = HybridHost(HybridRunParams(duration_s=args.duration), load_quarter_car(), model,
                          CompensatorParams(mode=mode), SafetyParams(growth_windows=100))
        run_offline(host, VirtualRig(model, ActuatorParams(), RigParams()))
        sl = host.road.evaluated
        xt, xm = host.record[0, sl], host.record[2, sl]
        ride = host.ride_metrics() or {}
        print(f"| {mode} | {np.sqrt(np.mean((xm - xt) ** 2) / np.mean(xt ** 2)) * 100:.2f} | "
              + " | ".join(f"{(ride[k] / host.reference_metrics[k] - 1) * 100:+.2f} %"
                           if k in ride else "–" for k in RIDE_KEYS)
              + f" | {time.perf_counter() - t0:.1f} |")


    if args.twin_chain:
        twin_chain(root / "twin", args.duration)


#: the fading specimen: the sport damper whose oil thins as it warms (a small lumped heat
#: capacity: the dyno's tests warm it tens of kelvin)
FADE = {"viscosity_temperature": {"temperature_coefficient_per_k": 0.03,
                                  "reference_temperature_c": 25.0,
                                  "heat_capacity_j_per_k": 200.0,
                                  "cooling_time_constant_s": 600.0}}


def twin_chain(tmp: Path, duration_s: float) -> None:
    from damper_emulator.params import load_config, save_config, with_extensions

    tmp.mkdir()
    save_config(with_extensions(load_config(), FADE), tmp / "faded.yaml")
    ch = channel(60)
    bus = ["--can-interface", "udp_multicast", "--can-channel", ch]
    rig = subprocess.Popen([*CLI, "virtual-rig", *bus, "--params", str(tmp / "faded.yaml")],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert rig.stderr is not None
    for line in rig.stderr:
        if line.startswith("[virtual-rig] on "):
            break
    threading.Thread(target=rig.stderr.read, daemon=True).start()
    steps = [
        ("dyno quasi-static on the rig", ["dyno", "--protocol", "quasi-static", "--amplitude",
                                          "0.05", "--cycles", "1", "--out", str(tmp / "rig"),
                                          *bus]),
        ("dyno chirp on the rig", ["dyno", "--protocol", "chirp", "--duration", "30",
                                   "--v-end", "1.2", "--out", str(tmp / "rig"), *bus]),
        ("identify", ["identify", "--quasi-static", str(tmp / "rig" / "quasi_static.csv"),
                      "--chirp", str(tmp / "rig" / "chirp.csv"), "--out",
                      str(tmp / "identified.yaml")]),
        ("hybrid, the identified twin", ["hybrid", "--out", str(tmp / "ride"), "--duration",
                                         f"{duration_s:g}", "--twin",
                                         str(tmp / "identified.yaml"), *bus]),
    ]
    times = {}
    try:
        for name, cmd in steps:
            t0 = time.perf_counter()
            proc = subprocess.run([*CLI, *cmd], capture_output=True, text=True)
            times[name] = time.perf_counter() - t0
            if proc.returncode != 0:
                print(f"\n{name} failed: {proc.stderr.strip().splitlines()[-1:]}")
                return
    finally:
        rig.send_signal(2)
        rig.wait(timeout=30)
    t0 = time.perf_counter()
    proc = subprocess.run([*CLI, "diagnose", "--params", str(tmp / "identified.yaml"),
                           "--quasi-static", str(tmp / "rig" / "quasi_static.csv"),
                           "--chirp", str(tmp / "rig" / "chirp.csv"), "--validate",
                           str(tmp / "ride" / "ride_measured.csv"), "--json",
                           str(tmp / "diagnose.json")], capture_output=True, text=True)
    times["diagnose"] = time.perf_counter() - t0
    ride = json.loads((tmp / "ride" / "hybrid.json").read_text())
    diag = json.loads((tmp / "diagnose.json").read_text()) if proc.returncode == 0 else {}
    print("\n## Twin: a specimen fading with temperature, identified and diagnosed on the "
          "rig\n")
    twin = ride["twin"]
    print(f"Ride with the identified twin: tracking NRMS {ride['tracking']['nrms'] * 100:.2f} "
          f"%, oil {ride['link']['temperature_c']:.1f} °C at the end; twin residual "
          f"{twin['residual_rms_first_n']:.0f} N r.m.s. over the ride's first 2 s, "
          f"{twin['residual_rms_last_n']:.0f} N over its last (as it came, without the "
          f"online correction: {twin['online']['without']['residual_rms_first_n']:.0f} and "
          f"{twin['online']['without']['residual_rms_last_n']:.0f} N).\n")
    rms = diag.get("rms_before", {}), diag.get("rms_after", {})
    print(f"Diagnosis: **{diag.get('family', 'failed')}** "
          f"({diag.get('effect', proc.stderr.strip().splitlines()[-1:])}); held-out "
          f"ride_measured.csv {rms[0].get('ride_measured.csv', float('nan')):.1f} → "
          f"{rms[1].get('ride_measured.csv', float('nan')):.1f} N.\n")
    print("| step | time [s] |\n|---|---|")
    for name, seconds in times.items():
        print(f"| {name} | {seconds:.0f} |")


if __name__ == "__main__":
    main()
