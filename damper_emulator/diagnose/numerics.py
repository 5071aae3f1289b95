"""The model's own integration error on the records, which no parameter removes.

A damper is continuous; the model steps eq 2 on sub-steps of at most
``numerics.max_substep_s`` (docs/model.md §2.1).  What that leaves differs from effect to
effect: the paper's model and most extensions are within a newton of their converged force
on the paper's chirp at the default 0.5 ms, a cavity or a short valve lag several newtons.
:func:`check_substep` measures it on the diagnosis's own records, for the model after the
diagnosis: the force as the records hold it on the model's sub-step and on half of it.
Second order, the error of the sub-step is about 4/3 of that change; where an event falls
within a sub-step (a cavity's opening) up to twice it.  The diagnosis reports it
(:class:`SubstepCheck`, the JSON's ``numerics``) and says so where it is not small against
the noise: the remedy is a shorter ``numerics.max_substep_s`` in the data sheet.  The
library's rounds run the same check on the model with the effects they found, and where it
fails fit it again on half the sub-step before weighing each effect against the others
(:meth:`~damper_emulator.diagnose.rounds.LibraryRounds.refine`; the JSON's
``numerics.refined_from``): on the model's sub-step an effect can stand in for another's
integration error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from damper_emulator.acquisition.rig import RigParams
from damper_emulator.diagnose.base import Record
from damper_emulator.diagnose.outcome import pooled_rms
from damper_emulator.model.compressible import DamperModel
from damper_emulator.validation import rms

__all__ = ["SUBSTEP_NOISE_FRACTION", "SubstepCheck", "check_substep"]

#: The model is integrated finely enough for the records where halving its sub-step moves
#: its force (pooled r.m.s. over the files) by at most this fraction of the noise level:
#: its integration error is then at most about the noise's half (first order) and adds at
#: most an eighth to the residual's r.m.s. in quadrature.
SUBSTEP_NOISE_FRACTION = 0.5


@dataclass(frozen=True)
class SubstepCheck:
    """What halving the model's sub-step ``max_substep_s`` [s] moves of its force as the
    records hold it [N r.m.s.]: pooled over the files (``change_n``) and per file, against
    the noise level of what the model leaves (``noise_n``)."""

    max_substep_s: float
    change_n: float
    noise_n: float
    per_file: dict[str, float]

    @property
    def converged(self) -> bool:
        """The change is at most :data:`SUBSTEP_NOISE_FRACTION` of the noise level."""
        return self.change_n <= SUBSTEP_NOISE_FRACTION * self.noise_n

    def sentence(self) -> str:
        """One paragraph for the report."""
        h = self.max_substep_s
        text = (f"Halving the model's sub-step ({1e3 * h:.3g} ms, `numerics.max_substep_s`) "
                f"moves its force by {self.change_n:.2f} N r.m.s. over the files, against a "
                f"noise level of {self.noise_n:.2f} N: ")
        if self.converged:
            return text + "the model's integration leaves nothing that matters here."
        return (text + "the model's own integration leaves about that much (a form "
                "difference no parameter removes, and one a short lag can take). Set "
                f"`numerics.max_substep_s` to {1e3 * h / 2:.3g} ms or less in the data sheet "
                "and run the identification and the diagnosis again (each simulation takes "
                "twice as long).")

    def refinement_sentence(self) -> str:
        """One sentence for the report where this check made the rounds halve the
        sub-step."""
        return (f"The model with the effects the rounds found moved by {self.change_n:.2f} N "
                f"r.m.s. on halving its sub-step, against a noise level of "
                f"{self.noise_n:.2f} N: it was fitted again, and every fit after it (the "
                "effects weighed against each other, the rig's delay, the discovery), on "
                f"{1e3 * self.max_substep_s / 2:.3g} ms sub-steps, which the model after "
                "keeps (`numerics.max_substep_s`).")

    def to_json(self) -> dict[str, Any]:
        return {"max_substep_s": self.max_substep_s, "change_on_halving_n": self.change_n,
                "noise_n": self.noise_n, "converged": self.converged,
                "change_on_halving_per_file_n": dict(self.per_file),
                "noise_fraction": SUBSTEP_NOISE_FRACTION}


def check_substep(model: DamperModel, records: Sequence[Record], rig: RigParams | None,
                  noise_n: float) -> SubstepCheck:
    """:class:`SubstepCheck` of ``model`` over ``records`` (every sample that counts, each
    file through its chain or the estimated ``rig``), against the noise level
    ``noise_n`` [N]."""
    h = model.cfg.numerics.max_substep_s
    finer = model.with_max_substep(h / 2.0)
    change = {rec.name: (rec.simulate(model, rig=rig) - rec.simulate(finer, rig=rig))[rec.start:]
              for rec in records}
    return SubstepCheck(h, pooled_rms(list(change.values())), noise_n,
                        {name: rms(d) for name, d in change.items()})
