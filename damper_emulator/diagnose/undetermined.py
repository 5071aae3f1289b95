"""Where the fit files leave an effect's law undetermined, and what lies there.

A fit determines a law only where its files went.  An effect found on the fit files may
have a part that they cannot determine: a hydraulic stop tested with the paper's
programme, whose files reach the stroke's ends only in the quasi-static test at 5 mm/s,
has its spring in them but not its law of the speed
(:data:`~damper_emulator.diagnose.candidates.ORIFICE_SPEED_SPAN`).  Held out on a sine
that enters the stops at 0.6 m/s, the stop found leaves a residual there that is not the
sign of an effect the library lacks: the files cannot tell the law there.

A candidate says where (:attr:`~damper_emulator.diagnose.candidates.Candidate.
undetermined`, from its fitted values) and why (its ``limit``).  Step 7
(:func:`damper_emulator.diagnose.selection.weigh_effects`) then weighs the effects on the
held-out samples outside those regions when most of what they left lies inside them, and
the report says how much lies there (:class:`Undetermined`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from damper_emulator.diagnose.base import Record
from damper_emulator.diagnose.candidates import Candidate
from damper_emulator.diagnose.outcome import STRUCTURE_RATIO, noise_level

__all__ = ["MIN_UNDETERMINED_SHARE", "Undetermined", "determined_masks", "explained_where",
           "power_share", "split_power", "undetermined_findings"]

#: step 7 weighs the effects where the fit files determine their laws when at least this
#: share of the structured power they left on the held-out files lies where they do not
MIN_UNDETERMINED_SHARE = 0.5


def split_power(residuals: Sequence[np.ndarray], where: Sequence[np.ndarray],
                noise_from: Sequence[np.ndarray] | None = None) -> tuple[float, float]:
    """The structured power [N²] of ``residuals`` (the square less each file's noise level
    squared, from ``noise_from``, else from ``residuals`` themselves) summed over the
    samples ``where`` and over the rest: ``(where, rest)``."""
    sums = [0.0, 0.0]
    for r, m, ref in zip(residuals, where, noise_from or residuals, strict=True):
        s2 = noise_level(ref) ** 2
        for k, part in enumerate((r[m], r[~m])):
            sums[k] += float(np.dot(part, part)) - s2 * part.size
    return sums[0], sums[1]


def explained_where(before: Sequence[np.ndarray], after: Sequence[np.ndarray],
                    where: Sequence[np.ndarray]) -> float:
    """:func:`~damper_emulator.diagnose.outcome.explained_fraction` over the samples
    ``where`` alone (noise levels from ``after``, each whole file's)."""
    p0, _ = split_power(before, where, after)
    p1, _ = split_power(after, where)
    return 1.0 - max(p1, 0.0) / p0 if p0 > 0.0 else 0.0


def power_share(residuals: Sequence[np.ndarray], where: Sequence[np.ndarray]) -> float:
    """The share of the structured power of ``residuals`` over the samples ``where``."""
    p_in, p_out = split_power(residuals, where)
    total = max(p_in, 0.0) + max(p_out, 0.0)
    return max(p_in, 0.0) / total if total > 0.0 else 0.0


def _regions(candidates: Sequence[Candidate], values: Sequence[Mapping[str, float]],
             rec: Record) -> list[tuple[Candidate, np.ndarray]]:
    """Each candidate's undetermined region on the counted samples of ``rec``."""
    out = []
    for c, v in zip(candidates, values, strict=True):
        if c.undetermined is not None:
            out.append((c, np.asarray(c.undetermined(rec.data, {**c.held, **v}),
                                      dtype=bool)[rec.start:]))
    return out


def determined_masks(candidates: Sequence[Candidate], values: Sequence[Mapping[str, float]],
                     held: Sequence[Record]) -> list[np.ndarray] | None:
    """Per held-out record, its counted samples where the fit files determine the laws of
    every one of ``candidates`` (fitted to ``values``); ``None`` where none has a region
    the files leave undetermined."""
    if all(c.undetermined is None for c in candidates):
        return None
    masks = []
    for rec in held:
        m = np.ones(rec.counted, dtype=bool)
        for _, region in _regions(candidates, values, rec):
            m &= ~region
        masks.append(m)
    return masks


@dataclass(frozen=True)
class Undetermined:
    """What one effect's undetermined region holds of the held-out residual."""

    effect: str
    #: why the fit files leave it undetermined, in words
    limit: str
    #: share of the held-out samples in the region
    samples: float
    #: share there of the structured power of the held-out residual after the diagnosis
    power: float
    #: per held-out file: the share of its samples in the region
    files: dict[str, float]

    def sentence(self) -> str:
        """What it means, in words."""
        return (f"{self.effect}: {self.limit}.  {100 * self.power:.0f} % of the held-out "
                f"residual's structured power lies where these files leave its law "
                f"undetermined ({100 * self.samples:.0f} % of the held-out samples): no fit "
                "of them can tell that part, and a fit file that goes there can.")

    def to_json(self) -> dict[str, object]:
        return {"effect": self.effect, "limit": self.limit, "samples_share": self.samples,
                "power_share": self.power, "files": self.files, "text": self.sentence()}


def undetermined_findings(candidates: Sequence[Candidate],
                          values: Sequence[Mapping[str, float]], held: Sequence[Record],
                          residuals: Sequence[np.ndarray]) -> list[Undetermined]:
    """Each of ``candidates`` (fitted to ``values``) whose undetermined region holds
    structure of the held-out ``residuals`` (of the records ``held``, in order): an r.m.s.
    there above :data:`~damper_emulator.diagnose.outcome.STRUCTURE_RATIO` × the noise
    level."""
    per_record = [_regions(candidates, values, rec) for rec in held]
    noise2 = float(np.mean([noise_level(r) ** 2 for r in residuals])) if residuals else 0.0
    out = []
    for k, c in enumerate(c for c in candidates if c.undetermined is not None):
        regions = [regs[k][1] for regs in per_record]
        n = sum(int(m.sum()) for m in regions)
        if n == 0:
            continue
        p_in, _ = split_power(residuals, regions)
        if p_in / n <= (STRUCTURE_RATIO ** 2 - 1.0) * noise2:
            continue
        out.append(Undetermined(
            effect=c.effect, limit=c.limit,
            samples=n / sum(m.size for m in regions),
            power=power_share(residuals, regions),
            files={r.name: float(m.mean()) for r, m in zip(held, regions)}))
    return out
