"""Report of a diagnosis: overlay plots, ranking, tables and the extended parameter file.

:func:`write_report` writes into a directory

* ``report.md``: the effects added step by step with their fitted parameters and
  uncertainties, the paper's parameters identified and re-identified, r.m.s. per file
  (identified, refitted, after), every round's candidates, the thresholds and the floor;
* ``overlay_<file>.png`` per held-out file: measured force, the identified model and the
  model after the diagnosis against displacement, velocity and time, with the residuals;
* ``residual_before_<file>.png`` (and ``residual_after_<file>.png`` with an effect) per
  held-out file: the residual analysis of :mod:`damper_emulator.diagnose.residual`;
* ``ranking.png``: every candidate's held-out r.m.s. reduction and ΔBIC;
* ``params_with_effect.yaml``: the re-identified parameters plus the effects found, a params
  file every command and the emulator load (only when an effect was added, or a
  discovered term is significant: then as ``damper.extensions.discovered_term``);
* ``params_refit.yaml``: the paper's model alone, re-identified jointly;
* ``rig_estimated.yaml`` where the chain was estimated (no ``--rig``) and its delay taken:
  the chain the model after the diagnosis was scored through, a rig file for
  ``validate --rig`` (with ``params_with_effect.yaml``, or ``params_refit.yaml`` when
  nothing was added).

matplotlib is imported only here.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from damper_emulator.acquisition import save_rig
from damper_emulator.diagnose.base import Record
from damper_emulator.diagnose.outcome import FRICTION, TERM_MOVED_FACTOR, Diagnosis
from damper_emulator.diagnose.residual import plot_residual, residual_record
from damper_emulator.params import save_config
from damper_emulator.validation import report_stem

#: the ranking plot's reduction axis starts here [%]; worse candidates are clipped
RANKING_FLOOR_PCT = -50.0


def _added(diag: Diagnosis) -> list[str]:
    """What the model after the diagnosis adds to the paper's: the effects, and a
    discovered term in the model."""
    return ([s.candidate.effect for s in diag.steps]
            + (["the discovered term"] if diag.term is not None else []))


def plot_overlay(path: Path, diag: Diagnosis, rec: Record) -> Path:
    """Measured force, identified model and model with the chosen effect on one file."""
    from damper_emulator.dyno.plots import new_figure, save

    d = rec.data
    before = rec.simulate(diag.base_model)
    # as the rig recorded it in this file: with what is fitted per file
    after = rec.as_recorded(diag.model_after(), rig=diag.rig_after())
    k = rec.start
    label_after = "+ " + " + ".join(_added(diag)) if _added(diag) else "refitted"
    # the axes placed by hand (as residual.plot_residual's): constrained layout would
    # double the drawing's time, once per held-out file
    fig = new_figure(13.0, 8.0, layout=None)
    fig.subplots_adjust(left=0.07, right=0.985, bottom=0.07, top=0.93, hspace=0.28,
                        wspace=0.18)
    axes = fig.subplots(2, 2)
    for ax, xs, xlabel in ((axes[0, 0], d.displacement * 1e3, "displacement [mm]"),
                           (axes[0, 1], rec.velocity, "velocity [m/s]")):
        ax.plot(xs[k:], d.force[k:], color="0.6", lw=2.5, label="measured")
        ax.plot(xs[k:], before[k:], color="tab:red", lw=1.0, label="identified model")
        ax.plot(xs[k:], after[k:], color="tab:blue", lw=1.0, ls="--", label=label_after)
        ax.set_xlabel(xlabel)
        ax.set_ylabel("force [N, rebound +]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    t = d.time - d.time[0]
    ax = axes[1, 0]
    ax.plot(t, d.force - before, color="tab:red", lw=0.8,
            label=f"measured − identified: r.m.s. {diag.rms_before[rec.name]:.1f} N")
    ax.plot(t, d.force - after, color="tab:blue", lw=0.8,
            label=f"measured − model {label_after}: r.m.s. "
                  f"{diag.rms_after[rec.name]:.1f} N")
    ax.axvspan(0.0, t[k], color="0.9", label="start-up, not counted")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("residual [N]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    ax.plot(rec.velocity[k:], (d.force - before)[k:], ".", ms=1.5, color="tab:red",
            label="before")
    ax.plot(rec.velocity[k:], (d.force - after)[k:], ".", ms=1.5, color="tab:blue",
            label="after")
    ax.set_xlabel("velocity [m/s]")
    ax.set_ylabel("residual [N]")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, markerscale=6)
    role = "held out" if rec.held_out else "identification file"
    fig.suptitle(f"{rec.name} ({role}): diagnosis {diag.family}"
                 + (f" / {diag.effect}" if diag.effect else ""))
    return save(fig, path)


def plot_series(path: Path, diag: Diagnosis) -> Path:
    """What moves over the series: each kind taken, its per-file values (± 1σ) over the
    files' places in the series, and its line."""
    from damper_emulator.dyno.plots import new_figure, save

    series = diag.series
    assert series is not None and series.taken  # (the caller's test)
    fig = new_figure(7.0 * len(series.taken), 4.5)
    axes = np.atleast_1d(fig.subplots(1, len(series.taken)))
    order = sorted(series.positions, key=lambda n: series.positions[n])
    for ax, d in zip(axes, series.taken):
        values = d.values()
        # the values less the coefficients: the reference's value (0 for the zero)
        base = d.reference_level()
        names = [n for n in order if n in values]
        x = np.array([series.positions[n] for n in names])
        y = np.array([values[n] for n in names])
        e = np.array([d.std.get(n, 0.0) for n in names])
        ax.errorbar(x, y, yerr=np.where(np.isfinite(e), e, 0.0), fmt="o", color="tab:blue",
                    capsize=3, label="per file ± 1σ")
        ax.plot([series.positions[order[0]]], [base], "s", color="0.3",
                label=f"{order[0]} (the reference)")
        if x.size >= 2 and math.isfinite(d.line.slope_std):
            xs = np.array([min(series.positions.values()), max(series.positions.values())])
            ax.plot(xs, base + d.line.y0 + d.line.slope * (xs - d.line.x0), color="0.4",
                    lw=1.0, label=f"line, R² {d.line.r2:.2f}")
        for xi, n in zip(x, names):
            ax.annotate(n, (xi, 0.0), xycoords=("data", "axes fraction"), rotation=60,
                        fontsize=6, ha="left", va="bottom")
        ax.set_xlabel("place in the series" + (" [s]" if x.size and np.ptp(x) > len(x)
                                               else " (file)"))
        ax.set_ylabel(f"{d.kind.parameter} [{d.kind.unit}]")
        ax.set_title(f"{d.kind.name} ({'the rig' if d.kind.cause == 'rig' else 'the damper'})",
                     fontsize=9)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("What moves from file to file (the first file is the reference)")
    return save(fig, path)


def plot_ranking(path: Path, diag: Diagnosis) -> Path:
    """Held-out r.m.s. reduction and ΔBIC of every candidate."""
    from damper_emulator.diagnose.outcome import MAX_DELTA_BIC, MIN_SCORE
    from damper_emulator.dyno.plots import new_figure, save

    ranking = diag.ranking[::-1]
    names = [f"{c.candidate.effect}\n({c.candidate.family})" for c in ranking]
    fig = new_figure(12.0, 0.45 * len(ranking) + 2.0)
    ax1, ax2 = fig.subplots(1, 2, sharey=True)
    y = np.arange(len(ranking))
    colors = ["tab:green" if c.significant else "0.6" for c in ranking]
    scores = [100.0 * c.score for c in ranking]
    floor = RANKING_FLOOR_PCT
    ax1.barh(y, [max(v, floor) for v in scores], color=colors)
    for yi, v in zip(y, scores):
        if v < floor:  # far worse than the identified model: clipped, value written
            ax1.text(floor, yi, f" {v:+.0f} %", va="center", fontsize=7)
    ax1.set_xlim(left=max(min(min(scores, default=0.0), 0.0) - 5.0, floor),
                 right=max(100.0, max(scores, default=0.0) + 5.0))
    ax1.axvline(100.0 * MIN_SCORE, color="k", ls="--", lw=0.8,
                label=f"significance {100 * MIN_SCORE:g} %")
    ax1.set_yticks(y, names, fontsize=8)
    ax1.set_xlabel("held-out r.m.s. reduction [%]")
    ax1.grid(True, axis="x", alpha=0.3)
    ax1.legend(fontsize=8)
    dbic = [c.delta_bic for c in ranking]
    ax2.barh(y, [math.copysign(math.log10(1.0 + abs(b)), -b) for b in dbic], color=colors)
    ax2.axvline(math.log10(1.0 - MAX_DELTA_BIC), color="k", ls="--", lw=0.8,
                label=f"ΔBIC ≤ {MAX_DELTA_BIC:g}")
    ax2.set_xlabel("evidence: sign(−ΔBIC) log10(1 + |ΔBIC|)")
    ax2.grid(True, axis="x", alpha=0.3)
    ax2.legend(fontsize=8)
    fig.suptitle(f"Candidates ranked: diagnosis {diag.family}"
                 + (f" / {diag.effect}" if diag.effect else ""))
    return save(fig, path)


def _fmt(x: Any) -> str:
    if x is None:
        return "–"
    if isinstance(x, float):
        if not math.isfinite(x):
            return "∞"
        return f"{x:.4g}"
    return str(x)


def _fmt_sd(x: float | None) -> str:
    """A σ: ``undetermined`` where the data show no slope (None in the JSON, ∞ in the
    fit's output)."""
    return "undetermined" if x is None or not math.isfinite(x) else _fmt(x)


def _base_table(diag: Diagnosis) -> list[str]:
    """The paper's parameters: identified, after the diagnosis, ± 1σ."""
    from damper_emulator.diagnose.base import BASE_PARAMETERS, config_value

    doc = diag.base_after_json()
    if doc is None:
        return []
    cfg = diag.base_model.cfg
    lines = ["| parameter | identified | after | ± 1σ | unit |", "|---|---|---|---|---|"]
    for bp in BASE_PARAMETERS:
        after = doc["values"].get(bp.path)
        if after is None:
            continue
        replaced = bp.path not in doc["uncertainties"]
        held = " (replaced by the effect)" if replaced else ""
        sd = "–" if replaced else _fmt_sd(doc["uncertainties"][bp.path])
        lines.append(f"| {bp.path} | {_fmt(config_value(cfg, bp.path))} | {_fmt(after)}{held} | "
                     f"{sd} | {bp.unit} |")
    return lines


def _pruned_lines(pruned: list[dict]) -> list[str]:
    """The effects tried away once the search ended (the JSON's ``pruned``)."""
    if not pruned:
        return []
    lines = ["", "Once the search ended, each effect added before the last was tried away: "
             "the others refitted without it, the gain of the effects with it on the "
             "held-out files.", ""]
    for p in pruned:
        lines.append(f"- {p['effect']} ({p['family']}): {100 * p['held_out_gain']:+.1f} %, "
                     f"ΔBIC {p['delta_bic']:.0f}: "
                     + ("it went (it had stood in for part of an effect added after it)"
                        if p["went"] else "kept"))
    return lines


def markdown(diag: Diagnosis, params_file: str = "") -> str:
    """The report's text; ``params_file``: the identified parameters as the report names
    them (:func:`named_from`)."""
    doc = diag.to_json()
    effects = doc["effects"]
    title = diag.family + (f" ({', '.join(e['effect'] for e in effects)})" if effects else "")
    lines = [f"# Diagnosis: {title}", ""]
    if params_file:
        lines += [f"Identified parameters: {params_file}.", ""]
    if effects:
        lines += ["Effects added by forward selection, each fitted together with the paper's "
                  "parameters and the effects before it; the gain is on the held-out files, "
                  "against the model of the step before.", ""]
        if diag.pair_gain is not None:
            lines += ["Found together: neither alone was significant; the pair cuts the "
                      f"held-out r.m.s. by {100 * diag.pair_gain:.1f} % against the refitted "
                      "model.", ""]
        lines += ["| step | effect | family | held-out gain | ΔBIC |", "|---|---|---|---|---|"]
        for k, (e, st) in enumerate(zip(effects, diag.steps), 1):
            lines.append(f"| {k} | {e['effect']} | {e['family']} | "
                         f"{100 * e['held_out_gain']:.1f} % | {st.delta_bic:.0f} |")
        lines += _pruned_lines(doc["pruned"])
        for e, st in zip(effects, diag.steps):
            c = st.candidate
            lines += ["", f"**{e['effect']}** ({e['family']})"
                      + (f": {c.note}" if c.note else ""), "",
                      "| parameter | fitted | ± 1σ | unit | bounds |", "|---|---|---|---|---|"]
            for p in c.parameters:
                f = e["fitted"][p.name]
                lines.append(f"| {p.name} | {_fmt(f['value'])} | {_fmt_sd(f['std'])} | "
                             f"{p.unit} | {_fmt(p.lo)} .. {_fmt(p.hi)} |")
        lines += ["", "Model written to `params_with_effect.yaml`: the re-identified paper's "
                      "parameters and " + ", ".join(e["effect"] for e in effects) + ".", ""]
    elif diag.effect == "discovered":
        found = diag.discovered
        lines += ["No library effect explains the held-out residual; a term discovered in "
                  f"it is significant (`{found.expression if found else ''}`, section Term "
                  f"discovery): the family `{diag.family}` is its hint.", "",
                  "Model written to `params_with_effect.yaml`: the paper's parameters and "
                  "the term refitted together, the term as the extension "
                  "`discovered_term`, which the emulator, the ride and replay run.", ""]
    elif diag.effect == "drift":
        lines += [f"No library effect is added; a parameter of the damper moves over the "
                  f"test series (section The series): the family `{diag.family}` is its.",
                  ""]
    elif diag.family == "other" and diag.closest is not None:
        c = diag.closest
        # (two effects where they were only significant together: the pair search)
        named = " with ".join(f"**{k.effect}** ({k.family})" for k in c.candidates)
        lines += [f"Structure remains that the library does not explain.  The closest "
                  f"candidate, {named}, cuts the "
                  f"held-out r.m.s. by {100 * c.score:.1f} %, but the effects found remove "
                  f"only {100 * diag.explained:.0f} % of the residual's structured power; "
                  "none is added.", ""]
    elif diag.family == "other":
        lines += ["No candidate explains a significant part of the held-out residual, yet "
                  f"the refitted model's residual is {doc['structure_ratio_before']:.1f}× its "
                  "noise level and above the floor: structure remains that the library does "
                  "not explain.", ""]
    else:
        lines += ["Nothing to add: the refitted paper's model leaves a held-out residual "
                  f"within the floor ({diag.floor_n:.2f} N: the larger of "
                  f"{100 * doc['thresholds']['floor_force_fraction']:g} % of the force r.m.s. "
                  f"and {doc['thresholds']['floor_noise_factor']:g}× the noise level "
                  f"{diag.noise_n:.2f} N) or without structure, and no candidate is "
                  "significant."
                  + ("  What the identified model missed was the rig's (section What the "
                     "rig did)." if any(f["kind"] not in ("filter", "skew", "delay")
                                        for f in doc["measurement"]) else ""), ""]
    if diag.scale is not None and diag.scale.bound_note():
        lines += ["**The oil's stiffness.** " + diag.scale.bound_note(), ""]
    for u in diag.undetermined:
        lines += ["**What these files cannot tell.** " + u.sentence()
                  + ("  The effects are weighed where the files determine their laws."
                     if diag.steps and diag.explained < doc["thresholds"]["min_explained"]
                     else ""), ""]
    if diag.numerics is not None and not diag.numerics.converged:
        lines += ["**The model's integration.** " + _numerics_text(diag), ""]
    lines += (_rig_lines(doc) + _series_lines(diag) + _chain_lines(doc["acquisition"])
              + _discovery_lines(diag))
    lines += ["## The paper's parameters", "",
              "Identified (`identify`'s staged fits) and after the joint fit of the "
              "diagnosis (simulated over the identification files, with the effects above):",
              "", *_base_table(diag), "",
              "## Residual r.m.s. per file [N]", "",
              "| file | role | identified | rig taken out | refitted | after | change |",
              "|---|---|---|---|---|---|---|"]
    refit = doc["refit"]["rms"] if doc["refit"] else {}
    for r in diag.records:
        b, a = diag.rms_before[r.name], diag.rms_after[r.name]
        ch = f"{100 * (a / b - 1):+.1f} %" if b > 0 else "–"
        lines.append(f"| {r.name} | {'held out' if r.held_out else 'fit'} | {b:.2f} | "
                     f"{_fmt(diag.rms_before_rig.get(r.name))} | "
                     f"{_fmt(refit.get(r.name))} | {a:.2f} | {ch} |")
    lines += ["", "*identified*: `identify`'s model on the files as recorded; *rig taken "
                  "out*: the same model, the lines of interference taken out of the files "
                  "(the zero and gain that move over the series are taken out of the "
                  "refitted model and after); *refitted*: the paper's model alone, "
                  "re-identified jointly (the reference of the first round).", "",
              f"Structure ratio of the held-out residual (r.m.s. / noise level): "
              f"{diag.structure_before:.2f} identified, {diag.structure_after:.2f} after.  "
              f"Floor {diag.floor_n:.2f} N, noise level {diag.noise_n:.2f} N (of what is left "
              f"after: {diag.noise_after_n:.2f} N).", ""]
    if diag.numerics is not None and diag.numerics.converged:
        lines += [_numerics_text(diag), ""]
    for k, rnd in enumerate(diag.rounds, 1):
        lines += [f"## Round {k}", "",
                  "| effect | family | held-out gain | ΔBIC | significant | parameters | "
                  "time |", "|---|---|---|---|---|---|---|"]
        for c in rnd:
            pars = ", ".join(f"{n} {_fmt(v)}" for n, v in c.values.items())
            lines.append(f"| {c.candidate.effect} | {c.candidate.family} | "
                         f"{100 * c.score:+.1f} % | {c.delta_bic:.0f} | "
                         f"{'yes' if c.significant else 'no'} | {pars} | {c.seconds:.1f} s |")
        lines.append("")
    th = doc["thresholds"]
    lines += [f"Significant: the present model's held-out residual above the floor, a "
              f"held-out gain ≥ {100 * th['min_score']:g} % and ΔBIC ≤ "
              f"{th['max_delta_bic']:g}; at most {th['max_effects']} effects.  `other` when "
              f"none is and the residual exceeds {th['structure_ratio']:g}× its noise level "
              f"and the floor, or when the effects remove less than "
              f"{100 * th['min_explained']:g} % of its structured power.  The first 50 ms of "
              "each file are not counted (start-up from equilibrium).", "",
              f"Diagnosis took {diag.seconds:.1f} s.", ""]
    return "\n".join(lines)


def _rig_lines(doc: dict[str, Any]) -> list[str]:
    """The report's section on what the rig did (the JSON's ``measurement``)."""
    found = doc["measurement"]
    lines = ["## What the rig did", ""]
    if not found:
        return [*lines, "Nothing beyond the measurement chain below: no interference on the "
                        "force channel, no zero or gain that moves over the series.", ""]
    lines += ["Left out of every fit and score before any effect was weighed: the rig's, "
              "not the damper's.", "", "| kind | value | unit | channel | evidence |",
              "|---|---|---|---|---|"]
    for f in found:
        lines.append(f"| {f['kind']} | {_fmt(f['value'])} | {f['unit']} | {f['channel']} | "
                     f"{f['evidence']} |")
    return [*lines, ""]


def _series_lines(diag: Diagnosis) -> list[str]:
    """The report's section on what moves from file to file (the JSON's ``drift``)."""
    series = diag.series
    if series is None:
        return []
    lines = ["## The series", ""]
    if not series.taken:
        return [*lines, "Nothing moves from file to file beyond the noise (the zero, a gain, "
                        "the gas charge, the friction and the valves were each fitted per "
                        "file; none was significant).", ""]
    order = sorted(series.positions, key=lambda n: series.positions[n])
    lines += ["Fitted per file beside the damper's model, every file of the series (the "
              "first is the reference); a damper's parameter must also follow the series.",
              "", "| file | " + " | ".join(f"{d.kind.parameter} [{d.kind.unit}]"
                                           for d in series.taken) + " |",
              "|---|" + "---|" * len(series.taken)]
    for name in order:
        cells = []
        for d in series.taken:
            v = d.values().get(name)
            cells.append("reference" if v is None else
                         f"{_fmt(v)} ± {_fmt_sd(d.std.get(name))}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("")
    for d in series.taken:
        cause = ("the rig's" if d.kind.cause == "rig"
                 else f"the damper's (family `{d.kind.family}`)")
        lines.append(f"- **{d.kind.name}**: {d.kind.doc}; {cause}.  ΔBIC {d.delta_bic:.0f}, "
                     f"explains {100 * d.explained:.0f} % of the series' structured "
                     f"residual; its line over the series R² {d.r2:.2f}."
                     + (f"  A change of the {d.ambiguous_with} fits nearly as well: the data "
                        "do not tell them apart." if d.ambiguous_with else ""))
    return [*lines, ""]


def _numerics_text(diag: Diagnosis) -> str:
    """The model's integration error after the diagnosis, and the rounds' halving of its
    sub-step where they made one (:mod:`damper_emulator.diagnose.numerics`)."""
    refined = diag.numerics_refined
    return ((refined.refinement_sentence() + "  " if refined is not None else "")
            + diag.numerics.sentence())


def _chain_lines(acq: dict[str, Any]) -> list[str]:
    """The report's section on the measurement chain (the JSON's ``acquisition``)."""
    lines = ["## The measurement chain", ""]
    if acq["source"] == "given":
        f = acq["rig"]["force"]
        lines.append(f"Given (`--rig`): the force channel's filter {f['filter']}"
                     + (f" of order {f['order']} at {_fmt(f['cutoff_hz'])} Hz"
                        if f["filter"] != "none" else "")
                     + f"; the force is recorded {1e3 * acq['force_delay_s']:.3g} ms late "
                     "against the displacement.  The model's force passes through it.")
    elif acq["source"] == "estimated":
        sd = acq["force_delay_std_s"]
        lines.append(f"Estimated (no `--rig`): the force's delay against the displacement "
                     f"{1e3 * acq['force_delay_s']:.4g} ms ± "
                     f"{_fmt_sd(None if sd is None else 1e3 * sd)} ms (1σ), freed in every "
                     f"fit as the rig's, never an effect: {acq['reading']}.  "
                     "`rig_estimated.yaml` holds it, for `validate --rig`.")
    else:
        # no --rig and no delay in the model after: the chain candidate competed in
        # every round (or with the effects) and was not kept
        lines.append("Estimated (no `--rig`): the force's delay against the displacement "
                     "competed with the effects as the rig's and was not kept; the model's "
                     "force is compared as it is.  The log gives each round's figures.")
    return [*lines, ""]


def _discovery_lines(diag: Diagnosis) -> list[str]:
    """The report's section on the discovered term."""
    found = diag.discovered
    if found is None:
        return []
    lines = ["## Term discovery", ""]
    if not found.features:
        return [*lines, f"Not run or nothing found: {found.reason}.", ""]
    verdict = ("significant" if found.significant else
               "not significant (the candidates' rules), not added")
    lines += [f"What the library left, regressed on the dictionary of motion and model "
              f"states (stability selection, then least squares): `{found.expression}`.",
              "",
              f"Variables: {', '.join(found.variables)}; family hint: "
              f"**{found.family_hint or 'none'}**.  Held-out gain "
              f"{100 * found.held_out_gain:+.1f} %, ΔBIC {found.delta_bic:.0f}: {verdict}.",
              "", "| term | coefficient | ± 1σ | unit | selected in |", "|---|---|---|---|---|"]
    for f, c, sd in zip(found.features, found.coefficients, found.std):
        freq = found.frequency.get(f.symbol)
        lines.append(f"| `{f.symbol}` | {_fmt(float(c))} | {_fmt_sd(float(sd))} | {f.unit} | "
                     f"{'–' if freq is None else f'{100 * freq:.0f} %'} |")
    lines += ["", "| held-out file | before [N] | with the term [N] |", "|---|---|---|"]
    for name, b in found.rms_held_out_before.items():
        lines.append(f"| {name} | {b:.2f} | {found.rms_held_out_after.get(name, b):.2f} |")
    if found.per_file:
        lines += ["", "Each part fitted on each file alone, the model held (a term that reads "
                      "as physics is one in every test):", "",
                  "| file | " + " | ".join(f"`{f.symbol}` [{f.unit}]" for f in found.features)
                  + " |", "|---|" + "---|" * len(found.features)]
        for name, parts in found.per_file.items():
            lines.append(f"| {name} | " + " | ".join(f"{_fmt(c)} ± {_fmt_sd(sd)}"
                                                   for c, sd in parts) + " |")
    lines += ["", f"**Ready to trust?** {found.trust()}."]
    moved = diag.term_moved()
    if moved:
        lines += ["", "**What the term took from the model.** Refitted with the term, these "
                  "of the paper's parameters moved by more than "
                  f"{TERM_MOVED_FACTOR:g}× from the model it was added to: "
                  + "; ".join(f"`{k}` {_fmt(b)} → {_fmt(a)}" for k, (b, a) in moved.items())
                  + ".  The term holds part of what they held: read it with them, as their "
                  "law in another form, not only as an effect beside them."]
    friction = diag.term_friction()
    if friction is not None:
        lines += ["", f"**Its friction with eq 4's.** `{FRICTION}` {_fmt(friction.after)} N "
                  f"and the term's {_fmt(friction.term)} N · tanh(ẋ / "
                  f"{1e3 * friction.sign_m_s:.3g} mm/s) are {_fmt(friction.together)} N of "
                  f"friction at speed, against {_fmt(friction.before)} N in the model it was "
                  f"added to: {friction.reading()}."]
    return [*lines, ""]


def plot_discovered(path: Path, diag: Diagnosis) -> Path:
    """The discovered term on each held-out file: the force the model after the library
    lacks (measured less model) and the term, against the variable the term's largest
    part depends on, and against each other (on the diagonal where the term explains it)."""
    from damper_emulator.diagnose.discovery import PLOTTED
    from damper_emulator.dyno.plots import new_figure, save

    found = diag.discovered
    assert found is not None
    fig = new_figure(12, 4.8)
    axes = fig.subplots(1, 2)
    label = PLOTTED[found.main_variable][0]
    lim = 0.0
    for name, (term, missing, var) in found.series.items():
        pts = axes[0].plot(var, missing, ".", ms=1.5, alpha=0.35,
                           label=f"{name}: measured − model")
        axes[0].plot(var, term, ".", ms=1.0, color=pts[0].get_color(), alpha=0.9)
        axes[1].plot(term, missing, ".", ms=1.5, alpha=0.35, label=name)
        lim = max(lim, float(np.max(np.abs(term))), float(np.max(np.abs(missing))))
    axes[0].set_xlabel(label)
    axes[0].set_ylabel("force [N] (dots: measured − model; dark: the term)")
    axes[0].set_title(f"residual against {found.main_variable}", fontsize=9)
    axes[1].plot([-lim, lim], [-lim, lim], "k--", lw=0.8, label="explained exactly")
    axes[1].set_xlabel("the discovered term [N]")
    axes[1].set_ylabel("measured − model [N]")
    axes[1].set_title(f"held-out gain {100 * found.held_out_gain:+.1f} %, "
                      f"{'significant' if found.significant else 'not significant'}",
                      fontsize=9)
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, markerscale=6)
    fig.suptitle(_wrapped(f"discovered: {found.expression}"), fontsize=9)
    return save(fig, path)


def _wrapped(text: str, width: int = 110) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def named_from(path: str, folder: Path) -> str:
    """``path`` as a report in ``folder`` names it: a markdown link relative to ``folder``
    where the file lies beside the folder or below it (the report and its parameters move
    together), else the path as given."""
    if not path:
        return ""
    rel = Path(os.path.relpath(Path(path).resolve(), folder.resolve()))
    if rel.parts[:1] == ("..",) and ".." in rel.parts[1:]:
        return f"`{path}`"
    return f"[{rel.name}]({rel.as_posix()})"


def write_report(diag: Diagnosis, out_dir: str | Path, params_file: str = "",
                 progress=None) -> list[Path]:
    """Write the report files (module docstring) into ``out_dir``; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda msg: None)
    files = []
    # the model after holds an effect or a term: params_with_effect.yaml, the plots after
    with_effect = diag.chosen is not None or diag.term is not None
    for rec in diag.records:
        if rec.held_out:
            files.append(plot_overlay(out / f"overlay_{report_stem(rec.name)}.png", diag, rec))
            say(f"wrote {files[-1]}")
            models = [("before", diag.base_model, None)]
            if with_effect:
                models.append(("after", diag.model_after(), diag.rig_after()))
            for when, model, rig in models:
                path = out / f"residual_{when}_{report_stem(rec.name)}.png"
                what = ("identified model" if when == "before" else "model with "
                        + " + ".join(_added(diag)))
                files.append(plot_residual(path, residual_record(model, rec.data, rig),
                                           title=f"{rec.name}: residual of the {what}"))
                say(f"wrote {path}")
    found = diag.discovered
    if found is not None and found.features:
        files.append(plot_discovered(out / "discovered.png", diag))
        say(f"wrote {files[-1]}")
    files.append(plot_ranking(out / "ranking.png", diag))
    say(f"wrote {files[-1]}")
    if diag.series is not None and diag.series.taken:
        files.append(plot_series(out / "series.png", diag))
        say(f"wrote {files[-1]}")
    if with_effect:
        path = out / "params_with_effect.yaml"
        save_config(diag.model_after().cfg, path)
        files.append(path)
        say(f"wrote {path}")
    if diag.refit is not None:
        path = out / "params_refit.yaml"
        save_config(diag.refit.model().cfg, path)
        files.append(path)
        say(f"wrote {path}")
    rig = diag.rig_after()
    if rig is not None:
        path = out / "rig_estimated.yaml"
        params = "params_with_effect" if with_effect else "params_refit"
        save_rig(rig, path, _wrapped(
            "The measurement chain damper-hil diagnose estimated (no --rig): "
            f"{diag.acquisition_json()['reading']}.", 88)
            + f"\nUse: damper-hil validate --params {params}.yaml --rig {path.name} FILE ...")
        files.append(path)
        say(f"wrote {path}")
    md = out / "report.md"
    text = markdown(diag, named_from(params_file, out))
    text += "\n## Figures\n\n" + "\n".join(f"![{p.name}]({p.name})" for p in files
                                           if p.suffix == ".png") + "\n"
    md.write_text(text)
    files.append(md)
    say(f"wrote {md}")
    return files
