"""Plain-text tables of the ride studies' documents: the figure-10 and figure-13 comparison
with the paper (:func:`comparison_table`) and the figure-11 speed sweep
(:func:`sweep_table`)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from ride_sim.study_paper import LABELS


def _fmt(key: str, value: float) -> str:
    if key.startswith("dtl"):
        return f"{value / 1e3:.3f}"
    if key.startswith("sws"):
        return f"{value:.4f}"
    return f"{value:.3f}"


_ROW_LABELS = {"sws": ("SWS", "m"), "accel_w": ("accel Wk", "m/s2"),
               "accel": ("accel unweighted", "m/s2"), "dtl": ("DTL", "kN")}


def _row_label(key: str) -> str:
    ac = key.endswith("_ac")
    k = key[:-3] if ac else key
    if k == "sws_mean":
        return "SWS mean [m]"
    base = k.split("_rms")[0] if "_rms" in k else k.split("_peak")[0]
    what, unit = _ROW_LABELS[base]
    what += " about mean" if ac else ""
    if "_rms" in k:
        return f"{what} rms [{unit}]"
    return f"{what} peak {'+' if k.endswith('pos') else '-'} [{unit}]"


#: Rows of :func:`comparison_table` (those present in the document are printed).
TABLE_KEYS = ("sws_rms", "sws_rms_ac", "sws_mean", "accel_w_rms", "accel_rms", "dtl_rms",
              "sws_peak_pos", "sws_peak_neg", "sws_peak_pos_ac", "sws_peak_neg_ac",
              "accel_w_peak_pos", "accel_w_peak_neg", "accel_peak_pos", "accel_peak_neg",
              "dtl_peak_pos", "dtl_peak_neg")


def comparison_table(doc: Mapping[str, Any], keys: Iterable[str] = TABLE_KEYS) -> str:
    """Plain-text table of a figure-10 or figure-13 document: per output and
    representation the mean, its std over seeds (figure 10), the paper's value and the
    ratio simulated / paper."""
    reps = [r for r in doc["representations"] if r in doc]
    seeds = any(doc[r].get("seeds", 1) > 1 for r in reps)
    cols = ("sim", "±std", "paper", "ratio") if seeds else ("sim", "paper", "ratio")
    width = 9 * len(cols)
    lines = [f"{'output':<30}" + "".join(f"|{LABELS[r]:^{width}}" for r in reps),
             f"{'':<30}" + "".join("|" + "".join(f"{c:>9}" for c in cols) for _ in reps)]
    for key in keys:
        if not any(key in doc[r] for r in reps):
            continue
        row = f"{_row_label(key):<30}"
        for r in reps:
            e = doc[r]
            cells = [_fmt(key, e[key])] if key in e else ["-"]
            if seeds:
                std = e.get("spread", {}).get(key, {}).get("std")
                cells.append(_fmt(key, std) if std is not None else "")
            paper = e.get("paper", {}).get(key)
            cells += ([_fmt(key, paper), f"{e[key] / paper:.2f}"] if paper is not None
                      else ["", ""])
            row += "|" + "".join(f"{c:>9}" for c in cells)
        lines.append(row)
    return "\n".join(lines)


def sweep_table(doc: Mapping[str, Any]) -> str:
    """Plain-text table of a figure-11 document (weighted acceleration r.m.s.)."""
    reps = [r for r in doc["representations"] if r in doc]
    lines = [f"{'speed [m/s]':>11}" + "".join(f"{LABELS[r] + ' aw [m/s2]':>26}" for r in reps)]
    for i, v in enumerate(doc["speeds_m_s"]):
        lines.append(f"{v:>11g}" + "".join(
            f"{doc[r]['accel_w_rms'][i]:>18.3f} ±{doc[r]['accel_w_rms_std'][i]:<6.3f}"
            for r in reps))
    return "\n".join(lines)
