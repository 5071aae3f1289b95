"""The work of one damper of a fleet, as one Dask task: identify, validate, diagnose.

:func:`run_damper` is pure computation on the data it is given (:class:`DamperJob`: the
parsed files, the data sheet) and returns everything to write (:class:`DamperResult`): a
worker needs no file system shared with the client, and a task that is run again (its
worker lost) does the same work.  The steps are those of the single commands, with their
defaults: ``identify --base``, ``validate`` on the sines, ``diagnose`` (its candidate fits
one after the other in this task: the fleet's parallelism is one damper per worker).

A user error (data the model cannot simulate, an identification that cannot start) is the
damper's ``status: error`` with the one-line reason; anything else is a bug and is raised,
for the runner to report as one.
"""

from __future__ import annotations

import json
import math
import os
import socket
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.errors import UserError, one_line
from damper_emulator.params import ModelConfig

#: the row's status of a damper whose work finished / could not be done
OK, ERROR = "ok", "error"
#: the identified parameters in the table, per fit of :class:`Identification`:
#: (fit attribute, column prefix)
FITS = (("quasi_static", ""), ("rebound", "rebound_"), ("compression", "compression_"))


@dataclass(frozen=True)
class DamperJob:
    """One damper's input to :func:`run_damper`."""

    id: str
    quasi_static: tuple[MeasuredData, ...]
    chirp: tuple[MeasuredData, ...]
    validate: tuple[MeasuredData, ...]
    base: ModelConfig
    base_file: str
    diagnose: bool = False
    effects: tuple[str, ...] | None = None


@dataclass
class DamperResult:
    """What :func:`run_damper` returns: the table row and the files to write into the
    damper's output folder (``{file name: text}``)."""

    row: dict[str, Any]
    files: dict[str, str] = field(default_factory=dict)


def error_row(damper_id: str, reason: str, **extra: Any) -> dict[str, Any]:
    """The row of a damper whose work could not be done."""
    return {"id": damper_id, "status": ERROR, "reason": reason, **extra}


def _json(doc: Any) -> str:
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def _pooled_rms(errors: list[np.ndarray]) -> float:
    e = np.concatenate(errors) if errors else np.zeros(0)
    return float(math.sqrt(np.mean(e * e))) if e.size else float("nan")


def run_damper(job: DamperJob) -> DamperResult:
    """Identify, validate and (``job.diagnose``) diagnose one damper; module docstring."""
    started = time.perf_counter()
    where = {"worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        result = _work(job)
    except UserError as exc:
        return DamperResult(error_row(job.id, one_line(exc),
                                      wall_s=round(time.perf_counter() - started, 3),
                                      finished_unix_s=round(time.time(), 3), **where))
    result.row.update(wall_s=round(time.perf_counter() - started, 3),
                      finished_unix_s=round(time.time(), 3), **where)
    return result


def _work(job: DamperJob) -> DamperResult:
    from damper_emulator import validation
    from damper_emulator.identify.pipeline import identify
    from damper_emulator.model.compressible import DamperModel
    from damper_emulator.params import config_yaml

    row: dict[str, Any] = {"id": job.id, "status": OK, "reason": ""}
    files: dict[str, str] = {}
    t0 = time.perf_counter()
    ident = identify(list(job.quasi_static), list(job.chirp), job.base)
    row["identify_s"] = round(time.perf_counter() - t0, 3)
    files["identified.yaml"] = config_yaml(ident.config)
    files["identified.json"] = _json({
        "base_params_file": job.base_file,
        "quasi_static_files": [d.name for d in job.quasi_static],
        "chirp_files": [d.name for d in job.chirp], **ident.as_dict()})
    for attr, prefix in FITS:
        fit = getattr(ident, attr)
        for name, value, se in zip(fit.names, fit.values, fit.std_errors):
            row[f"{prefix}{name}"] = float(value)
            row[f"{prefix}{name}_se"] = float(se) if math.isfinite(se) else None
        row[f"{attr}_fit_rms_n"] = float(fit.rms)

    t0 = time.perf_counter()
    model = DamperModel(ident.config)
    checked = {d.name: validation.validate_file(model, d) for d in job.validate}
    errors = [r[validation.SERIES_KEY]["force_simulated"]
              - r[validation.SERIES_KEY]["force_measured"] for r in checked.values()]
    measured = [r[validation.SERIES_KEY]["force_measured"] for r in checked.values()]
    worst = max(checked, key=lambda n: checked[n]["rms_N"])
    row.update(validate_s=round(time.perf_counter() - t0, 3),
               validation_rms_n=_pooled_rms(errors),
               validation_relative_rms=_pooled_rms(errors) / _pooled_rms(measured),
               validation_worst_file=worst, validation_worst_rms_n=checked[worst]["rms_N"],
               validation_files=len(checked))
    files["validation.json"] = _json({
        "params_file": "identified.yaml",
        "files": {n: validation.json_summary(r) for n, r in checked.items()}})

    if job.diagnose:
        from damper_emulator.diagnose.selection import diagnose

        t0 = time.perf_counter()
        diag = diagnose(model, [*job.quasi_static, *job.chirp], list(job.validate),
                        list(job.effects) if job.effects else None, jobs=1,
                        n_quasi_static=len(job.quasi_static))
        doc = {"params_file": "identified.yaml", **diag.to_json()}
        files["diagnosis.json"] = _json(doc)
        after = [diag.rms_after[d.name] ** 2 * len(d) for d in job.validate]
        row.update(diagnose_s=round(time.perf_counter() - t0, 3),
                   diagnosis_family=diag.family,
                   diagnosis_effects=",".join(e["effect"] for e in doc["effects"]),
                   diagnosis_significant=bool(diag.significant),
                   diagnosis_rms_after_n=float(math.sqrt(sum(after)
                                                         / sum(len(d) for d in job.validate))))
    return DamperResult(row, files)
