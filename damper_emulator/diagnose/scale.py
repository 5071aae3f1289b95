"""The force's scale against the oil's stiffness: a stage of a diagnosis where the files
carry no measurement chain (:func:`weigh_scale`).

A load cell whose gain is ``g`` in every file records ``g F``.  The paper's model takes
most of it into its own constants (the gas charge, the friction, the valves' restrictions
and blow-off, eqs 3–10, all scale with the pressures), but not the oil's compressibility:
the pressures' rate of change (eq 1) is ``(Q_in − Q_out)/(α V)``, and with every pressure
``g`` times it holds only with ``α/g``.  The data sheet's α is the model's one absolute
pressure scale; where the tests are fast enough for the oil's lag to show, a 5 % gain on
a van damper's speed series left 32 N of the refit's held-out residual (8× the noise),
which a valve lag took and the answer named (``valve_dynamics``).

The stage refits the paper's model (with the rig's delay, where estimated) with α freed
(within :data:`~damper_emulator.diagnose.base.OIL_COMPRESSIBILITY_FACTOR` either side)
and without, and takes the scale, off its bounds (:data:`BOUND_MARGIN`), where it lowers
the effective BIC by :data:`~damper_emulator.diagnose.series.SERIES_MAX_DELTA_BIC` and
explains :data:`~damper_emulator.diagnose.series.MIN_SERIES_EXPLAINED` of what the refit
without it leaves (the tests a series' kind passes, :func:`~damper_emulator.diagnose.
series.refit_evidence`).  Taken, every later fit frees α within the same bounds, and the
finding is the rig's (``gain``): the data cannot tell a gain of every file alike from an
oil ``g`` times as stiff as the model's (a data sheet's α, free air), and say so.  With a
chain given (``--rig``) the force's gain is known and the stage does not run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from damper_emulator.diagnose.base import (
    ACQUISITION_DELAY,
    OIL_COMPRESSIBILITY,
    OIL_COMPRESSIBILITY_FACTOR,
)
from damper_emulator.diagnose.measurement import Finding
from damper_emulator.diagnose.outcome import StepFit, noise_level
from damper_emulator.diagnose.rounds import LibraryRounds
from damper_emulator.diagnose.series import (
    MIN_SERIES_EXPLAINED,
    SERIES_MAX_DELTA_BIC,
    refit_evidence,
)
from damper_emulator.diagnose.session import Session

__all__ = ["ScaleResult", "scale_findings", "weigh_scale"]

#: a fitted α within this factor of a bound of :data:`~damper_emulator.diagnose.base.
#: OIL_COMPRESSIBILITY_FACTOR` is at the bound: the fit wanted more than a load cell's
#: gain can be, and something else (a compliance, a lag) is in the data
BOUND_MARGIN = 1.01


@dataclass(frozen=True)
class ScaleResult:
    """The force's scale as the stage weighed it: the oil's compressibility the model
    had and the one freed [1/Pa], the evidence against the refit without it, and whether
    it was taken."""

    alpha_model: float
    alpha_fitted: float
    delta_bic: float
    explained: float
    taken: bool

    @property
    def at_bound(self) -> str:
        """``"stiffer"`` or ``"softer"`` where the freed α went to its bound (the data
        want the oil stiffer or softer than the data sheet's by more than a load cell's
        gain explains), ``"undetermined"`` where the fit gave none, else ``""``."""
        factor = OIL_COMPRESSIBILITY_FACTOR / BOUND_MARGIN
        if not math.isfinite(self.alpha_fitted):
            return "undetermined"
        if self.alpha_fitted <= self.alpha_model / factor:
            return "stiffer"
        return "softer" if self.alpha_fitted >= self.alpha_model * factor else ""

    def bound_note(self) -> str:
        """What a scale at its bound tells the user (``""`` where it is not)."""
        if self.at_bound in ("", "undetermined"):
            return ""
        return (f"The paper's model refitted with the oil's compressibility freed took it "
                f"to its bound ({self.alpha_fitted:.3g} against the identified model's "
                f"{self.alpha_model:.3g} 1/Pa, the most a load cell's gain explains): the "
                f"data want an oil {self.at_bound} than the model's by more than a gain. "
                "The diagnosis frees α only within a gain's range, so the rest goes to the "
                "effects. A valve lag or cavitation does this too; but where the model's α "
                "is a data sheet's, not the damper's, `identify --fit-alpha` fits it "
                "first.")

    @property
    def gain(self) -> float:
        """The force channel's gain that the fitted α stands for: ``α_model/α_fitted``."""
        return self.alpha_model / self.alpha_fitted

    def finding(self) -> Finding:
        """The rig's finding (module docstring)."""
        g = self.gain
        oil = "stiffer" if g > 1.0 else "softer"
        return Finding(
            "gain", g, "-", "force",
            f"one scale of the whole series: the paper's model refitted with the oil's "
            f"compressibility freed takes it from {self.alpha_model:.3g} to "
            f"{self.alpha_fitted:.3g} 1/Pa (ΔBIC {self.delta_bic:.0f}; it explains "
            f"{100 * self.explained:.0f} % of what the refit without it leaves): a gain of "
            f"{g:.4f} on the force channel, or an oil {abs(g - 1) * 100:.1f} % {oil} than "
            "the model's (its data sheet's α, free air); a gain of every file alike and "
            "the oil's compressibility cannot be told apart (a known gain is given with "
            "--rig)")

    def to_json(self) -> dict[str, float | bool]:
        return {"alpha_model_per_pa": self.alpha_model,
                "alpha_fitted_per_pa": self.alpha_fitted, "gain": self.gain,
                "delta_bic": self.delta_bic, "explained": self.explained,
                "taken": self.taken, "at_bound": self.at_bound}


def weigh_scale(session: Session, rounds: LibraryRounds, present: StepFit | None
                ) -> ScaleResult | None:
    """The force's scale (module docstring) on top of ``present`` (the paper's model
    refitted with the rig's delay; ``None``: the identified model as the series left
    it).  Taken, ``session.base_values`` hold the fitted α (and the refit's other
    paper's parameters), so every later fit frees it.  ``None`` where the files carry
    their chain."""
    if not session.estimate:
        return None
    say = session.say
    alpha = session.cfg.damper.oil_compressibility_per_pa
    tasks = [rounds.task(present, None),
             rounds.task(present, None, start={OIL_COMPRESSIBILITY: alpha})]
    say("the force's scale: the paper's model refitted with the oil's compressibility "
        "freed and without")
    without, with_alpha = rounds.execute(present, tasks, "the force's scale")
    records = session.records
    sigmas = [noise_level(session.base_res[r.name]) for r in records]
    dbic, explained = refit_evidence(sigmas, without.residuals(records),
                                     with_alpha.residuals(records), 1)
    fitted = float(with_alpha.out["base_values"][OIL_COMPRESSIBILITY])
    result = ScaleResult(alpha, fitted, dbic, explained, False)
    inside = not result.at_bound
    taken = bool(dbic <= SERIES_MAX_DELTA_BIC and explained >= MIN_SERIES_EXPLAINED
                 and inside)
    result = ScaleResult(alpha, fitted, dbic, explained, taken)
    say(f"the force's scale: α {alpha:.3g} → {fitted:.3g} 1/Pa (a gain of "
        f"{result.gain:.4f}), ΔBIC {dbic:.0f}, explains {100 * explained:.0f} % of what the "
        "refit without it leaves" + ("; taken: every later fit frees it" if taken else
                                     "; not taken" + ("" if inside else
                                                      " (at its bound: no gain)")))
    if result.bound_note():
        say(f"the force's scale: {result.bound_note()}")
    if taken:
        # the later fits start from the refit's paper's parameters (the delay competes
        # in the rounds as ever)
        session.base_values.update({k: float(v) for k, v in
                                    with_alpha.out["base_values"].items()
                                    if k != ACQUISITION_DELAY})
    return result


def scale_findings(result: ScaleResult | None) -> Sequence[Finding]:
    """The stage's finding, where it took the scale."""
    return [result.finding()] if result is not None and result.taken else []
