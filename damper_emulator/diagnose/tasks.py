"""One independent fit of a diagnosis as a picklable task (:class:`FitTask`) and
its runner (:func:`run_fit_task`), for any executor: a process pool, Dask workers.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from damper_emulator.acquisition.chain import ESTIMATED_DELAY_START_S
from damper_emulator.blas import one_blas_thread
from damper_emulator.diagnose.base import ACQUISITION_DELAY, PerFile, delay_rig, make_record
from damper_emulator.diagnose.candidates import candidates as make_candidates
from damper_emulator.diagnose.joint import JOINT_NFEV, joint_fit
from damper_emulator.diagnose.statistics import lag1
from damper_emulator.dyno.measured import MeasuredData
from damper_emulator.params import ModelConfig
from damper_emulator.validation import rms


@dataclass(frozen=True)
class FitTask:
    """One independent fit of a diagnosis, in plain picklable values: the identified
    configuration, the files, the cost weights, the present model (its paper's parameters
    and the effects ``accepted`` with their values) and the candidate ``effect`` to add
    (``None``: refit the present model alone)."""

    cfg: ModelConfig
    fit: tuple[MeasuredData, ...]
    held: tuple[MeasuredData, ...]
    weights: tuple[float, ...]
    base_values: Mapping[str, float]
    accepted: tuple[tuple[str, Mapping[str, float]], ...]
    effect: str | None
    nfev: int = JOINT_NFEV
    #: the first this many ``fit`` files are quasi-static tests, the others chirps
    n_quasi_static: int = 1
    #: the candidate's own fit of the round before (its paper's parameters, and its
    #: effects' values by name): the start of the other order (``joint_fit``)
    alternative: tuple[Mapping[str, float], Mapping[str, Mapping[str, float]]] | None = None
    #: the chain candidate: the present model with the estimated chain's delay added
    #: (``effect`` is ``None``)
    chain: bool = False
    #: what is fitted per file beside the model, by file name (``base.PerFile``)
    per_file: tuple[tuple[str, PerFile], ...] = ()


@one_blas_thread
def run_fit_task(task: FitTask) -> dict[str, Any]:
    """Run one :class:`FitTask` (in any process, with
    :data:`~damper_emulator.blas.FIT_BLAS_THREADS` BLAS threads): the joint fit and the
    plain figures the selection needs (per file: MSE, lag-1 autocorrelation and samples of
    the fit files, SSE of the held-out files)."""
    t0 = time.perf_counter()
    per_file = dict(task.per_file)
    fit = [make_record(d, False, per_file.get(d.name or d.path)) for d in task.fit]
    held = [make_record(d, True, per_file.get(d.name or d.path)) for d in task.held]
    cands = {c.effect: c for c in make_candidates(task.cfg, task.fit)}
    accepted = [(cands[e], v) for e, v in task.accepted]
    cand = cands[task.effect] if task.effect is not None else None
    base_values = dict(task.base_values)
    if task.chain:
        base_values.setdefault(ACQUISITION_DELAY, ESTIMATED_DELAY_START_S)
    jf = joint_fit(task.cfg, fit, task.weights, base_values, accepted, cand, task.nfev,
                   task.n_quasi_static, task.alternative)
    order = [c for c, _ in accepted] + ([cand] if cand is not None else [])
    model = jf.model(task.cfg, order)
    rig = delay_rig(jf.base_values)
    fit_res = [r.residual(model, rig=rig) for r in fit]
    held_res = [r.residual(model, rig=rig) for r in held]
    return {"effect": task.effect, "chain": task.chain,
            "effects": [c.effect for c in order],
            "base_values": {k: float(v) for k, v in jf.base_values.items()},
            "base_std": {k: float(v) for k, v in jf.base_std.items()},
            "values": [{k: float(v) for k, v in vals.items()} for vals in jf.values],
            "std": [{k: float(v) for k, v in sd.items()} for sd in jf.std],
            "fit": {r.name: {"mse": float(np.mean(x * x)), "rho": lag1(x), "n": int(x.size),
                             "rms": rms(x)} for r, x in zip(fit, fit_res)},
            "held": {r.name: {"sse": float(np.dot(x, x)), "rms": rms(x)}
                     for r, x in zip(held, held_res)},
            "reidentified": jf.reidentified, "friction_factor": jf.friction_factor,
            "evaluations": jf.evaluations, "seconds": time.perf_counter() - t0}
