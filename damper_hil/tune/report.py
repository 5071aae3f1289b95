"""What ``tune`` writes (docs/tune.md "Output").

* ``pareto.json`` (CONTRACT: ``{"designs": [{"objectives": {...}, "params_file": ...},
  ...]}``, plus the baseline, the chosen designs, the sensitivity ranking, the settings)
  and ``pareto.csv``: the feasible Pareto front;
* ``designs/design_NNNN.yaml``: a params file per front design (the whole damper, loadable
  by the emulator, ``dyno``, ``ride-study``, ``validate``);
* ``chosen_<name>.yaml``: the chosen designs (:data:`CHOICES`);
* ``designs.csv``: every design evaluated;
* ``pareto.png`` (the front, the baseline marked), ``fourteen_speed.png`` (the chosen
  designs' 14-speed curves against the baseline's), ``sensitivity.png``; ``summary.md``.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.dyno.plots import new_figure, save
from damper_emulator.params import ModelConfig, save_config
from damper_hil.tune.runner import TuneRun
from ride_sim import tuning as tu

#: the chosen designs: name → what it is
CHOICES = {
    "balanced": "the front design nearest the utopia point (each objective scaled to the "
                "front's range), among those that beat the baseline in every objective "
                "when any does",
    "comfort": "the lowest Wk body acceleration among the front designs no worse than the "
               "baseline in tyre load and working space (else on the whole front)",
    "road_holding": "the lowest dynamic tyre load among the front designs no worse than the "
                    "baseline in comfort and working space (else on the whole front)",
}
#: display scale and unit of each objective in tables and plots
SHOWN = {"accel_w_rms": (1.0, "m/s²"), "dtl_rms": (1.0, "N"), "sws_rms": (1e3, "mm")}


def _objectives(run: TuneRun, i: int) -> dict[str, float]:
    return {name: float(run.values[i, k]) for k, (name, _, _) in enumerate(tu.OBJECTIVES)}


def chosen(run: TuneRun, front: np.ndarray) -> dict[str, int]:
    """The index of each of :data:`CHOICES` among the designs (``front``: the mask of
    :meth:`TuneRun.front`)."""
    obj = run.objectives
    base = obj[0]
    out: dict[str, int] = {}
    better = front & tu.dominates_baseline(obj, base)
    out["balanced"] = tu.knee(obj, better if better.any() else front)
    for name, k, others in (("comfort", 0, (1, 2)), ("road_holding", 1, (0, 2))):
        ok = front & np.all(obj[:, others] <= base[list(others)], axis=1)
        pool = np.flatnonzero(ok if ok.any() else front)
        out[name] = int(pool[int(np.argmin(obj[pool, k]))])
    return out


def _design_name(i: int) -> str:
    return "baseline" if i == 0 else f"design_{i:04d}"


def write_results(run: TuneRun, base: ModelConfig, base_file: str, out: Path,
                  say: Callable[[Path], None] = lambda p: None) -> dict[str, Any]:
    """Every file of the module docstring; returns the ``pareto.json`` document."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "designs").mkdir(exist_ok=True)
    names = run.spec.variables
    front_mask = run.front()   # once: every file and plot below shows this front
    front = np.flatnonzero(front_mask)
    picks = chosen(run, front_mask)
    rho = tu.sensitivity(run.factors[1:], run.objectives[1:])
    designs = []
    for i in front:
        if i == 0:
            params_file = base_file
        else:
            path = out / "designs" / f"{_design_name(i)}.yaml"
            save_config(tu.design_config(base, run.factors[i], run.spec), path)
            params_file = str(path.relative_to(out))
        designs.append({
            "id": _design_name(i), "round": int(run.rounds[i]),
            "objectives": _objectives(run, i),
            "constraints": {
                "sws_peak_bump_m": float(run.values[i, tu.EVAL_COLUMNS.index("sws_peak_bump")]),
                "sws_peak_rebound_m": float(
                    run.values[i, tu.EVAL_COLUMNS.index("sws_peak_rebound")])},
            "factors": {n: float(f) for n, f in zip(names, run.factors[i])},
            "dominates_baseline": bool(tu.dominates_baseline(run.objectives[i:i + 1],
                                                             run.objectives[0])[0]),
            "params_file": params_file})
    for name, i in picks.items():
        path = out / f"chosen_{name}.yaml"
        save_config(tu.design_config(base, run.factors[i], run.spec), path)
        say(path)
    doc: dict[str, Any] = {
        "designs": designs,
        "baseline": {"params_file": base_file, "objectives": _objectives(run, 0),
                     "feasible": bool(run.feasible[0])},
        "chosen": {name: {"id": _design_name(i), "params_file": f"chosen_{name}.yaml",
                          "objectives": _objectives(run, i), "rule": CHOICES[name]}
                   for name, i in picks.items()},
        "objectives": {n: {"unit": u, "meaning": m} for n, u, m in tu.OBJECTIVES},
        "sensitivity": {
            obj: sorted(({"variable": v, "spearman": float(rho[j, k])}
                         for j, v in enumerate(names)),
                        key=lambda e: -abs(e["spearman"]))
            for k, (obj, _, _) in enumerate(tu.OBJECTIVES)},
        "evaluated": int(run.values.shape[0]), "feasible": int(run.feasible.sum()),
        "engine": run.engine, "wall_s": round(run.wall_s, 2),
        "round_s": [round(t, 2) for t in run.round_s],
        "settings": _settings_doc(run.spec)}
    path = out / "pareto.json"
    path.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
    say(path)
    _write_csv(out / "pareto.csv", run, front, front_mask, say)
    _write_csv(out / "designs.csv", run, np.arange(run.values.shape[0]), front_mask, say)
    for p in (plot_front(run, picks, front_mask, out / "pareto.png"),
              plot_fourteen_speed(run, base, picks, out / "fourteen_speed.png"),
              plot_sensitivity(run, rho, out / "sensitivity.png")):
        say(p)
    say(write_summary(doc, run, out))
    return doc


def _settings_doc(spec: tu.TuneSpec) -> dict[str, Any]:
    import dataclasses

    return {**dataclasses.asdict(spec.settings), "bounds": {
        v: list(getattr(spec.bounds, v)) for v in spec.variables}}


def _write_csv(path: Path, run: TuneRun, rows: np.ndarray, front: np.ndarray,
               say: Callable[[Path], None]) -> None:
    names = run.spec.variables
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "round", *names, *tu.EVAL_COLUMNS, "pareto"])
        for i in rows:
            w.writerow([_design_name(int(i)), int(run.rounds[i]),
                        *(f"{f:.6g}" for f in run.factors[i]),
                        *(f"{v:.6g}" for v in run.values[i]), int(front[i])])
    say(path)


def plot_front(run: TuneRun, picks: dict[str, int], front: np.ndarray, path: Path) -> Path:
    obj = run.objectives
    fig = new_figure(8, 5.5)
    ax = fig.subplots()
    infeasible = ~run.feasible
    ax.scatter(obj[~front & ~infeasible, 1], obj[~front & ~infeasible, 0], s=8,
               color="0.75", label="dominated")
    ax.scatter(obj[infeasible, 1], obj[infeasible, 0], s=8, marker="x", color="0.55",
               label="infeasible (travel or fault)")
    sc = ax.scatter(obj[front, 1], obj[front, 0], s=26, c=obj[front, 2] * 1e3,
                    cmap="viridis", label="Pareto front (colour: SWS r.m.s.)")
    fig.colorbar(sc, ax=ax, label="SWS r.m.s. [mm]")
    ax.scatter(obj[0, 1], obj[0, 0], s=160, marker="*", color="tab:red", zorder=5,
               label="baseline")
    labels: dict[int, list[str]] = {}
    for name, i in picks.items():
        labels.setdefault(i, []).append(name)
    for i, names in labels.items():
        ax.annotate(", ".join(names), (obj[i, 1], obj[i, 0]), xytext=(8, 8),
                    textcoords="offset points", fontsize=8,
                    arrowprops={"arrowstyle": "-", "lw": 0.6})
    ax.set_xlabel("dynamic tyre load r.m.s. [N] (road holding)")
    ax.set_ylabel("Wk body acceleration r.m.s. [m/s²] (comfort)")
    ax.set_title(f"{run.values.shape[0]} designs: comfort against road holding, mean over "
                 "the random roads\n(the front is in three objectives: a front design may "
                 "look dominated in this view)", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")
    save(fig, path, dpi=110)
    return path


def plot_fourteen_speed(run: TuneRun, base: ModelConfig, picks: dict[str, int], path: Path
                        ) -> Path:
    from damper_emulator.model.compressible import DamperModel
    from damper_emulator.model.representations import fourteen_speed_damper
    fig = new_figure(8, 5)
    ax = fig.subplots()
    curves = [("baseline", base, "k", "-")]
    styles = {"balanced": ("tab:blue", "-"), "comfort": ("tab:green", "--"),
              "road_holding": ("tab:orange", "-.")}
    for name, i in picks.items():
        curves.append((f"{name} ({_design_name(i)})",
                       tu.design_config(base, run.factors[i], run.spec), *styles[name]))
    for label, cfg, colour, ls in curves:
        table = fourteen_speed_damper(DamperModel(cfg))
        ax.plot(table.velocity_m_s, table.force_n, ls, color=colour, marker=".",
                label=label)
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.axvline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel("damper velocity [m/s] (rebound +)")
    ax.set_ylabel("force [N] (rebound +)")
    ax.set_title("14-speed curves (virtual dyno) of the chosen designs and the baseline")
    ax.legend(fontsize=8)
    save(fig, path, dpi=110)
    return path


def plot_sensitivity(run: TuneRun, rho: np.ndarray, path: Path) -> Path:
    names = run.spec.variables
    fig = new_figure(9, 0.45 * len(names) + 1.8)
    ax = fig.subplots()
    y = np.arange(len(names))
    width = 0.8 / len(tu.OBJECTIVES)
    for k, (obj, _, _) in enumerate(tu.OBJECTIVES):
        ax.barh(y + (k - 1) * width, rho[:, k], height=width, label=obj)
    ax.set_yticks(y, names, fontsize=8)
    ax.invert_yaxis()
    ax.axvline(0.0, color="0.4", lw=0.6)
    ax.set_xlim(-1, 1)
    ax.set_xlabel("Spearman rank correlation with the objective (+: a larger factor "
                  "raises it)")
    ax.set_title("Which valve constant moves which objective")
    ax.legend(fontsize=8)
    save(fig, path, dpi=110)
    return path


def write_summary(doc: dict[str, Any], run: TuneRun, out: Path) -> Path:
    base = doc["baseline"]["objectives"]
    lines = ["# Virtual damper tuning", "",
             f"- {tu.describe(run.spec.settings)}; {len(run.spec.variables)} variables, "
             "factors of the base damper's values.",
             f"- {doc['evaluated']} designs evaluated ({doc['feasible']} feasible), "
             f"{len(doc['designs'])} on the Pareto front; {doc['wall_s']:.1f} s on "
             f"{doc['engine']}.",
             f"- Baseline {'feasible' if doc['baseline']['feasible'] else 'INFEASIBLE'} "
             "(peak SWS within the travel, no damper fault).", "",
             "## Chosen designs", "",
             "| design | " + " | ".join(f"{n} [{SHOWN[n][1]}]" for n, _, _ in tu.OBJECTIVES)
             + " | params file |", "|---|" + "---|" * (len(tu.OBJECTIVES) + 1),
             "| baseline | " + " | ".join(f"{SHOWN[n][0] * base[n]:.4g}"
                                          for n, _, _ in tu.OBJECTIVES) + " | – |"]
    for name, c in doc["chosen"].items():
        cells = [f"{SHOWN[n][0] * c['objectives'][n]:.4g} "
                 f"({100 * (c['objectives'][n] / base[n] - 1):+.1f} %)"
                 for n, _, _ in tu.OBJECTIVES]
        lines.append(f"| {name} ({c['id']}) | " + " | ".join(cells)
                     + f" | `{c['params_file']}` |")
    lines += ["", *(f"- **{name}**: {rule}" for name, rule in CHOICES.items()), "",
              "## Sensitivity: which valve constant moves which objective", "",
              "Spearman rank correlation over every design evaluated (+: a larger factor "
              "raises the objective); the three strongest per objective:", ""]
    for obj, ranking in doc["sensitivity"].items():
        top = ", ".join(f"`{e['variable']}` {e['spearman']:+.2f}" for e in ranking[:3])
        lines.append(f"- **{obj}**: {top}")
    lines += ["", "![front](pareto.png)", "![14-speed](fourteen_speed.png)",
              "![sensitivity](sensitivity.png)", ""]
    path = out / "summary.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
