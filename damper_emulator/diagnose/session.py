"""What every stage of a diagnosis shares: the files as records, the identified model's
residual on them ("before"), the fits' cost weights, the candidates and the paper's
parameters a fit starts from (:class:`Session`, made by :func:`prepare`)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from damper_emulator.diagnose.base import (
    PerFile,
    Record,
    base_parameters,
    chain_unknown,
    make_record,
)
from damper_emulator.diagnose.candidates import Candidate
from damper_emulator.diagnose.candidates import candidates as make_candidates
from damper_emulator.diagnose.outcome import MIN_NOISE_FRACTION, noise_level
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.errors import UserError
from damper_emulator.model.compressible import DamperModel
from damper_emulator.params import ModelConfig
from damper_emulator.validation import rms

__all__ = ["Say", "Session", "check_inputs", "prepare"]

#: a diagnosis's progress messages
Say = Callable[[str], None]


@dataclass
class Session:
    """The records of a diagnosis and what every fit of it shares."""

    base: DamperModel
    records: list[Record]
    #: the identified model's residual ``F_sim − F_meas`` per file, and its r.m.s. [N]
    base_res: dict[str, np.ndarray]
    rms_before: dict[str, float]
    #: each identification file's cost weight, ``1/(√n σ_f)``
    weights: list[float]
    candidates: dict[str, Candidate]
    #: the paper's parameters every fit starts from (the identified values, in bounds)
    base_values: dict[str, float]
    #: no file carries its measurement chain: the rig's delay is estimated
    estimate: bool
    n_quasi_static: int
    nfev: int
    say: Say
    t_start: float = field(default_factory=time.perf_counter)
    #: what is fitted per file beside the model (the series' drift), by file name
    per_file: dict[str, PerFile] = field(default_factory=dict)

    @property
    def cfg(self) -> ModelConfig:
        return self.base.cfg

    @property
    def fit(self) -> list[Record]:
        return [r for r in self.records if not r.held_out]

    @property
    def held(self) -> list[Record]:
        return [r for r in self.records if r.held_out]

    def elapsed(self) -> float:
        return time.perf_counter() - self.t_start

    def with_per_file(self, per_file: Mapping[str, PerFile]) -> None:
        """Fit ``per_file`` beside the model from now on: every record, and the
        identified model's residual ("before" stays as recorded)."""
        self.per_file = dict(per_file)
        for r in self.records:
            r.per_file = self.per_file.get(r.name)


def check_inputs(base: DamperModel, fit_data: Sequence[MeasuredData],
                 held_out_data: Sequence[MeasuredData]) -> None:
    """One line for what a diagnosis cannot take: no identification or held-out file,
    two files of one name, a model that already has extensions."""
    if not fit_data or not held_out_data:
        raise UserError("diagnose needs identification files (quasi-static, chirp) and at "
                        "least one held-out validation file")
    names = [d.name or d.path for d in (*fit_data, *held_out_data)]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise UserError(f"two data files share the name {dup[0]!r}; names must differ")
    if base.cfg.damper.extensions is not None:
        raise UserError("diagnose needs the identified model without damper.extensions")


def records_of(fit_data: Sequence[MeasuredData], held_out_data: Sequence[MeasuredData]
               ) -> list[Record]:
    """The records of the identification files, then of the held-out files."""
    return ([make_record(d, False) for d in fit_data]
            + [make_record(d, True) for d in held_out_data])


def prepare(base: DamperModel, fit_data: Sequence[MeasuredData],
            held_out_data: Sequence[MeasuredData], effects: Sequence[str] | None,
            n_quasi_static: int, nfev: int, say: Say, t_start: float | None = None
            ) -> Session:
    """The session of a diagnosis of ``base`` on the files (as the measurement stage left
    them): the records, the residual before, the weights, the candidates
    (:func:`~damper_emulator.diagnose.candidates.candidates`) and the start values."""
    cfg = base.cfg
    records = records_of(fit_data, held_out_data)
    base_res = {r.name: r.residual(base) for r in records}
    fit = [r for r in records if not r.held_out]
    weights = []
    for r in fit:
        force_rms = rms(r.data.force[r.start:])
        sigma = max(noise_level(base_res[r.name]), MIN_NOISE_FRACTION * force_rms, 1e-9)
        weights.append(1.0 / (math.sqrt(r.counted) * sigma))
    cands = make_candidates(cfg, [r.data for r in fit], effects)
    session = Session(
        base=base, records=records, base_res=base_res,
        rms_before={r.name: rms(base_res[r.name]) for r in records}, weights=weights,
        candidates={c.effect: c for c in cands},
        base_values={p.name: p.start for p in base_parameters(cfg, [r.data for r in fit])},
        estimate=chain_unknown([r.data for r in records]), n_quasi_static=n_quasi_static,
        nfev=nfev, say=say)
    if t_start is not None:
        session.t_start = t_start
    return session
