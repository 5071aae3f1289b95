"""What the rig did: the measurement findings of a diagnosis, and the stage that takes
interference out of the records before any effect is scored.

A finding (:class:`Finding`) is the rig's, never the damper's: a line on the force channel
(:mod:`damper_emulator.diagnose.interference`), the load cell's zero offset and drift and a
gain change over the series (:mod:`damper_emulator.diagnose.series`), the chain's filters
and skew (given with ``--rig``, or the delay estimated).  The JSON's ``measurement`` lists
them (``kind``, ``value``, ``unit``, ``channel``, ``evidence``, and ``per_file`` where the
value differs by file).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.base import Record
from damper_emulator.diagnose.interference import Line, find_lines, fit_lines, without_lines
from damper_emulator.diagnose.series import Drift
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.model.compressible import DamperModel

__all__ = ["Finding", "chain_findings", "drift_findings", "line_findings", "screen_delay",
           "take_out_lines"]


@dataclass(frozen=True)
class Finding:
    """One thing the rig did (module docstring)."""

    kind: str
    value: float
    unit: str
    channel: str
    evidence: str
    per_file: Mapping[str, float] | None = None

    def to_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {"kind": self.kind, "value": self.value, "unit": self.unit,
                               "channel": self.channel, "evidence": self.evidence}
        if self.per_file is not None:
            doc["per_file"] = dict(self.per_file)
        return doc


#: the delay a first look at the rig tries, within the estimated chain's bounds, to
#: this fraction of its range
SCREEN_DELAY_XTOL = 1e-3


def screen_delay(base: DamperModel, records: Sequence[Record]) -> RigParams | None:
    """A first look at the rig's delay, where no file carries its chain: the delay of the
    force against the displacement (:func:`~damper_emulator.acquisition.chain.
    estimated_rig`) that best fits the identified model to the identification records,
    each simulated once (the delay only filters the forces).  Only for what is weighed
    before the library's rounds, which estimate the delay with the damper (the rig's
    lines and the series: behind a 150 Hz load-cell filter the identified model's chirp
    residual was 86 N of phase, above which a 3 N line did not stand out); ``None`` where
    a file carries its chain."""
    from scipy.optimize import minimize_scalar

    from damper_emulator.acquisition.chain import ESTIMATED_DELAY_BOUND_S, estimated_rig

    if any(r.data.acquisition is not None for r in records):
        return None
    fit = [r for r in records if not r.held_out]
    raws = [r.simulate(base) for r in fit]
    scales = [max(float(np.mean(r.data.force[r.start:] ** 2)), 1e-12) for r in fit]

    def cost(tau: float) -> float:
        rig = estimated_rig(tau)
        return sum(float(np.mean((r.recorded(raw, rig)[r.start:] - r.data.force[r.start:])
                                 ** 2)) / sc for r, raw, sc in zip(fit, raws, scales))
    best = minimize_scalar(cost, bounds=(0.0, ESTIMATED_DELAY_BOUND_S), method="bounded",
                           options={"xatol": SCREEN_DELAY_XTOL * ESTIMATED_DELAY_BOUND_S})
    return estimated_rig(float(best.x)) if best.success else None


def take_out_lines(base: DamperModel, records: Sequence[Record],
                   say: Callable[[str], None], rig: RigParams | None = None
                   ) -> tuple[list[Line], dict[str, MeasuredData]]:
    """The stationary lines in the identified model's residual of ``records`` (through
    ``rig``, a first look at the chain where the files carry none)
    (:func:`~damper_emulator.diagnose.interference.find_lines`), fitted in every file,
    and every file's data with them taken out of its force (by name; unchanged where
    none was found)."""
    residuals = {}
    for r in records:
        k = r.start
        residuals[r.name] = (r.data.time[k:], -r.residual(base, rig=rig),
                             r.data.displacement[k:])
    lines = find_lines(residuals)
    if not lines:
        return [], {r.name: r.data for r in records}
    fitted = fit_lines(lines, {n: (t, res) for n, (t, res, _) in residuals.items()})
    out = {}
    for r in records:
        k = r.start
        full = np.zeros_like(r.data.force)
        full[k:] = fitted[r.name]
        if k:  # the skipped start: the same lines, continued backwards
            full[:k] = _continued(r.data.time, k, lines, r.name)
        out[r.name] = without_lines(r.data, full)
    for line in lines:
        say(f"measurement: {line.evidence()}")
    return lines, out


def _continued(t: np.ndarray, k: int, lines: Sequence[Line], name: str) -> np.ndarray:
    """The fitted lines of file ``name`` over its first ``k`` samples (their fit starts at
    sample ``k``)."""
    tt = t[:k] - t[k]
    out = np.zeros(k)
    for line in lines:
        if name in line.amplitudes_n:
            a, phi = line.amplitudes_n[name], line.phases_rad[name]
            fs = 1.0 / float(np.median(np.diff(t)))
            fa = abs(line.frequency_hz - fs * round(line.frequency_hz / fs))
            out += a * np.cos(2.0 * np.pi * fa * tt + phi)
    return out


def line_findings(lines: Sequence[Line]) -> list[Finding]:
    """A finding per line: its frequency [Hz] as the value, its amplitude per file."""
    return [Finding("interference", line.frequency_hz, "Hz", line.channel, line.evidence(),
                    dict(line.amplitudes_n)) for line in lines]


def drift_findings(drifts: Sequence[Drift]) -> list[Finding]:
    """The rig's kinds the series took as findings: the zero's offset (the largest over
    the files as the value, every file's) and its drift within the files (their
    weighted mean as the value), a gain (the largest change, as its factor)."""
    out = []
    for d in drifts:
        if d.kind.cause != "rig":
            continue
        values = d.values()
        evidence = (f"fitted per file, ΔBIC {d.delta_bic:.0f} over every file of the "
                    f"series; explains {100 * d.explained:.0f} % of the series' "
                    "structured residual")
        if d.ambiguous_with is not None:
            evidence += (f"; a change of the {d.ambiguous_with} fits nearly as well (the "
                         "data do not tell them apart)")
        if d.kind.name == "gain":
            value = max(values.values(), key=lambda v: abs(v - 1.0))
            out.append(Finding("gain", value, "-", "force", f"{d.kind.doc}: {evidence}",
                               values))
            continue
        out.append(Finding("zero_offset", max(values.values(), key=abs), "N", "force",
                           "the load cell's zero against the first file, at rest too: "
                           + evidence + f"; moves by {d.slope:+.3g} N per place in the "
                           f"series (R² {d.r2:.2f})", values))
        w = {k: 1.0 / s ** 2 for k, s in d.rates_std.items() if math.isfinite(s) and s > 0}
        if w:
            rate = sum(d.rates[k] * w[k] for k in w) / sum(w.values())
            spread = math.sqrt(1.0 / sum(w.values()))
            if abs(rate) > 3.0 * spread:
                out.append(Finding("zero_drift", rate, "N/s", "force",
                                   f"the load cell's zero drifting within the files: "
                                   f"{rate:+.3g} ± {spread:.2g} N/s, weighted over the "
                                   "files", dict(d.rates)))
    return out


def chain_findings(acquisition: Mapping[str, Any], given: RigParams | None) -> list[Finding]:
    """The chain's filters and skews as findings: given (``--rig``), each channel's
    filter and skew; estimated, the force's delay."""
    out = []
    if given is not None:
        for name in ("force", "displacement"):
            ch = getattr(given, name)
            if ch.filtered:
                out.append(Finding("filter", ch.cutoff_hz, "Hz", name,
                                   f"given (--rig): {ch.filter} of order {ch.order}"))
            if ch.skew_s:
                out.append(Finding("skew", ch.skew_s, "s", name, "given (--rig)"))
        force = given.force
        if force.gain != 1.0:
            out.append(Finding("gain", force.gain, "-", "force", "given (--rig)"))
        if force.zero_offset_n:
            out.append(Finding("zero_offset", force.zero_offset_n, "N", "force",
                               "given (--rig), at each file's first sample"))
        if force.zero_drift_n_per_s:
            out.append(Finding("zero_drift", force.zero_drift_n_per_s, "N/s", "force",
                               "given (--rig), within each file"))
        return out
    if acquisition.get("source") == "estimated":
        out.append(Finding("delay", float(acquisition["force_delay_s"]), "s", "force",
                           "estimated: " + str(acquisition.get("reading", ""))))
    return out


def replace_data(records: Sequence[Record], data: Mapping[str, MeasuredData]) -> None:
    """Each record's data replaced by ``data`` (by name)."""
    for r in records:
        r.data = dataclasses.replace(data[r.name])
