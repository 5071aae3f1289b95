"""The fleet's report: ``summary.md`` with its plots (docs/fleet.md "Summary").

* ``parameters.png``: every identified parameter across the fleet, one strip per
  parameter (valve constants on a log scale), flagged dampers in red and labelled;
* ``validation.png``: each damper's validation r.m.s. (pooled over its sines), flagged
  ones in red;
* ``diagnosis.png`` (with ``--diagnose``): how many dampers each diagnosis got.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.ticker import LogLocator, NullFormatter

from damper_emulator.dyno.plots import new_figure, save
from damper_emulator.errors import ESCAPE, printable
from damper_emulator.outputs import Outputs
from damper_hil.fleet.outliers import RULES, SCORED
from damper_hil.fleet.runner import FleetRun

#: the table's unit of each scored parameter (display scale, unit)
DISPLAY = {"gas_pressure_static_pa": (1e-6, "MPa"), "gas_volume_static_m3": (1e6, "cm³"),
           "friction_force_n": (1.0, "N"), "preload_pa": (1e-5, "bar")}
#: a strip uses a log scale when its values span more than this factor
LOG_SPAN = 10.0
#: the colours of the plots: ordinary and flagged dampers
COLOURS = ("tab:blue", "tab:red")


def _display(column: str) -> tuple[float, str]:
    for key, value in DISPLAY.items():
        if column.endswith(key):
            return value
    return 1.0, ""


def _values(rows: list[dict[str, Any]], column: str) -> tuple[list[str], np.ndarray]:
    pairs = [(r["id"], r.get(column)) for r in rows if r.get("status") == "ok"]
    pairs = [(i, float(v)) for i, v in pairs if isinstance(v, (int, float))
             and math.isfinite(v)]
    return [i for i, _ in pairs], np.array([v for _, v in pairs])


def plot_parameters(run: FleetRun, path: Path) -> Path:
    n = len(SCORED)
    cols = 3
    rows = math.ceil(n / cols)
    fig = new_figure(13, 2.0 * rows)
    axes = fig.subplots(rows, cols, squeeze=False)
    rng = np.random.default_rng(0)  # vertical jitter only, so that points do not overlap
    for ax, (column, log) in zip(axes.flat, SCORED):
        ids, v = _values(run.rows, column)
        scale, unit = _display(column)
        flagged = {i for i, fl in run.flags.items() if any(f.rule.column == column
                                                            for f in fl)}
        if v.size:
            jitter = rng.uniform(-0.3, 0.3, v.size)
            red = np.array([i in flagged for i in ids])
            ax.scatter(v[~red] * scale, jitter[~red], s=18, color=COLOURS[0])
            ax.scatter(v[red] * scale, jitter[red], s=28, color=COLOURS[1])
            for i, x, y, r in zip(ids, v * scale, jitter, red):
                if r:
                    ax.annotate(printable(i), (x, y), fontsize=7, color=COLOURS[1],
                                xytext=(3, 3), textcoords="offset points")
            ax.axvline(float(np.median(v)) * scale, color="0.5", lw=0.8, ls="--")
            if log and np.all(v > 0) and v.max() > LOG_SPAN * v.min():
                ax.set_xscale("log")
                # labels at 1, 2, 5 of each decade and none between: a span of a
                # decade or two would otherwise label every minor tick, overlapping
                ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
                ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_ylim(-1, 1)
        ax.set_yticks([])
        ax.set_title(f"{column}" + (f" [{unit}]" if unit else ""), fontsize=9)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle(f"Identified parameters of {len(run.rows)} dampers (dashed: the fleet's "
                 "median; red: flagged on that parameter)", fontsize=11)
    save(fig, path, dpi=110)
    return path


def plot_validation(run: FleetRun, path: Path) -> Path:
    ids, v = _values(run.rows, "validation_rms_n")
    fig = new_figure(max(6.0, 0.45 * len(ids) + 2), 3.6)
    ax = fig.subplots()
    colours = [COLOURS[bool(run.flags.get(i))] for i in ids]
    ax.bar(range(len(ids)), v, color=colours)
    ax.set_xticks(range(len(ids)), [printable(i) for i in ids], rotation=60, ha="right",
                  fontsize=8)
    ax.set_ylabel("validation r.m.s. [N]")
    if v.size:
        ax.axhline(float(np.median(v)), color="0.5", lw=0.8, ls="--")
    ax.set_title("Validation error per damper (pooled over its sines; red: flagged by any rule)")
    save(fig, path, dpi=110)
    return path


def plot_diagnosis(run: FleetRun, path: Path) -> Path:
    counts = Counter(r.get("diagnosis_family") for r in run.rows
                     if r.get("status") == "ok" and r.get("diagnosis_family"))
    fig = new_figure(7, 3.2)
    ax = fig.subplots()
    names = sorted(counts, key=lambda k: (-counts[k], k))
    ax.barh(names, [counts[k] for k in names], color=COLOURS[0])
    ax.invert_yaxis()
    ax.set_xlabel("dampers")
    ax.set_title("Diagnosis per damper")
    save(fig, path, dpi=110)
    return path


def write_summary(run: FleetRun, out: Path, outputs: Outputs) -> Path:
    """``out/summary.md`` and its plots, registered in ``outputs`` (committed by the
    caller); returns where the summary is written meanwhile."""
    rows = run.rows
    ok = [r for r in rows if r.get("status") == "ok"]
    errors = [r for r in rows if r.get("status") != "ok"]
    names = ["parameters.png", "validation.png"]
    if any(r.get("diagnosis_family") for r in ok):
        names.append("diagnosis.png")
    at = {name: outputs.file(out / name) for name in [*names, "summary.md"]}
    plots = [plot_parameters(run, at["parameters.png"]),
             plot_validation(run, at["validation.png"])]
    if "diagnosis.png" in at:
        plots.append(plot_diagnosis(run, at["diagnosis.png"]))
    lines = [f"# Fleet summary: {len(rows)} dampers", "",
             f"- {len(ok)} finished, {len(errors)} in error; "
             f"{len(run.resumed)} taken from an earlier run of this folder.",
             f"- Engine: {run.engine}; {run.wall_s:.1f} s in all.",
             "- Files: `results.csv` and `results.parquet` (one row per damper), and each "
             "damper's own folder.", ""]
    flagged = [(i, fl) for i, fl in run.flags.items() if fl]
    lines += ["## Flagged dampers", ""]
    if flagged:
        lines += ["| damper | rule | value | meaning |", "|---|---|---|---|"]
        for i, fl in flagged:
            for f in fl:
                lines.append(f"| {i} | {f.rule.name} | {f.detail} | {f.rule.meaning} |")
    else:
        lines.append("None." if len(ok) else "No damper finished.")
    lines += ["", "Rules (docs/fleet.md): "
              + "; ".join(f"`{r.name}`" for r in RULES if not r.name.startswith("atypical_"))
              + "; `atypical_<parameter>`: modified z-score beyond 3.5.", ""]
    if errors:
        lines += ["## Dampers in error", "", "| damper | reason |", "|---|---|"]
        lines += [f"| {r['id']} | {r.get('reason', '')} |" for r in errors]
        lines.append("")
    lines += ["## Identified parameters across the fleet", "",
              "| parameter | median | 10th–90th percentile | dampers |", "|---|---|---|---|"]
    for column, _ in SCORED:
        _, v = _values(rows, column)
        if v.size:
            lo, mid, hi = np.percentile(v, [10, 50, 90])
            lines.append(f"| {column} | {mid:.4g} | {lo:.4g} … {hi:.4g} | {v.size} |")
    lines += ["", *(f"![{Path(n).stem}]({n})" for n in names), ""]
    path = at["summary.md"]
    path.write_text("\n".join(lines), encoding="utf-8", errors=ESCAPE)
    return path
