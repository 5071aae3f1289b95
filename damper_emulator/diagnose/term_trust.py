"""Whether a discovered term reads as physics: each of its parts fitted on each file alone,
the model held (:func:`per_file_coefficients`), and one over the files
(:func:`stable_over`).  An inertia is one mass in every test; a term that takes the
model's error at each file's speeds is not one over the files."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.base import Record, TermSource
from damper_emulator.diagnose.statistics import fit_columns
from damper_emulator.model.compressible import DamperModel

__all__ = ["STABLE_SPREAD", "per_file_coefficients", "spread", "stable_over"]


#: a part's coefficient is one over the files when those that determine it (their 1σ
#: within half the coefficient) agree in sign and span at most this fraction of the
#: pooled value: an inertia is one mass in every test; a term that takes the model's
#: error at each file's speeds is not
STABLE_SPREAD = 0.5


def stable_over(per_file: Mapping[str, tuple[float, float]], pooled: float
                ) -> tuple[bool, str]:
    """Whether a coefficient fitted per file ``{file: (value, σ)}`` is one over the
    files (:data:`STABLE_SPREAD`), and why not."""
    determined = [c for c, sd in per_file.values()
                  if math.isfinite(sd) and sd <= 0.5 * abs(c)]
    if len(determined) < 2:
        return False, f"determined in {len(determined)} file(s) only"
    if any(c * pooled <= 0.0 for c in determined):
        return False, "its sign changes from file to file"
    width = (max(determined) - min(determined)) / abs(pooled)
    if width > STABLE_SPREAD:
        return False, (f"it spans {100 * width:.0f} % of its value over the files "
                       f"({min(determined):.4g} … {max(determined):.4g})")
    return True, ""


def spread(per_file: Mapping[str, tuple[float, float]], pooled: float) -> float:
    """How far a coefficient is from one over the files: the span of the values over the
    pooled value's magnitude (infinite where the sign changes)."""
    values = [c for c, _ in per_file.values()]
    if not values or any(c * pooled <= 0.0 for c in values):
        return math.inf
    return (max(values) - min(values)) / abs(pooled)


def per_file_coefficients(models: Sequence[DamperModel], source: TermSource,
                          fit: Sequence[Record], held: Sequence[Record],
                          rig: RigParams | None) -> dict[str, list[tuple[float, float]]]:
    """Each part's coefficient fitted on each file alone (the model and what is fitted per
    file held), with its 1σ: what the term is in every test.  ``models``: the model of
    each record of ``fit`` then ``held``, as the fit took it (a quasi-static test's own
    friction: :func:`~damper_emulator.diagnose.joint.record_models`)."""
    out = {}
    for model, rec in zip(models, [*fit, *held], strict=True):
        raw, cols = source(model, rec)
        k = rec.start
        force = rec.recorded(raw, rig)[k:]
        x = np.column_stack([rec.through_chain(cols[:, j], rig)[k:]
                             for j in range(cols.shape[1])])
        n_term = x.shape[1]
        if rec.per_file is not None:
            x = np.column_stack([x, rec.per_file.design(force)])
        c, sd, _ = fit_columns(x, rec.data.force[k:] - force)
        out[rec.name] = [(float(c[j]), float(sd[j])) for j in range(n_term)]
    return out
