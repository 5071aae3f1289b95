"""The rules that flag a damper of a fleet (docs/fleet.md "Outliers").

Each rule is one row of :data:`RULES`: the column it reads, its test, its threshold and
what it means to a damper engineer.  Two kinds:

* **engineering rules** against the fleet's median: a gas charge well below the others'
  (a leaking or under-filled gas chamber), a friction well above (a tight seal or rod
  guide), a validation error well above (the model describes this unit worse than the
  others: look at it), an effect the diagnosis found;
* **statistical rules** on every identified parameter: the modified z-score of Iglewicz
  and Hoaglin (1993), ``M = 0.6745 (x − median) / MAD``, flags ``|M| > 3.5`` (their
  recommendation; robust, so one bad unit does not hide another), when the value is also
  more than :data:`MIN_RELATIVE_DEVIATION` from the median.  The valve constants, which
  span decades, are scored on their logarithm.

Rules against the median need at least :data:`MIN_FLEET` dampers with results; with fewer
only the diagnosis rule applies.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: fewest dampers with results for a rule against the fleet's median
MIN_FLEET = 5
#: the modified z-score's constant: 0.6745 = Φ⁻¹(3/4) makes MAD/0.6745 the standard
#: deviation of a normal sample (Iglewicz & Hoaglin 1993)
MAD_TO_SIGMA = 0.6745
#: |M| above which a value is an outlier (Iglewicz & Hoaglin's recommendation)
ROBUST_Z_LIMIT = 3.5
#: a statistical flag also needs the value this far from the median (relative): a
#: production valve's or seal's tolerance, so that a tight fleet's tiny spread does not
#: flag a unit that is well within it
MIN_RELATIVE_DEVIATION = 0.05
#: the diagnosis's answers that are not a finding
NO_FINDING = ("none", "", None)


@dataclass(frozen=True)
class Rule:
    """One way a damper is flagged.

    ``test``: ``"below_median"`` (value < threshold × the fleet's median),
    ``"above_median"`` (value > threshold × median), ``"robust_z"`` (``|M|`` >
    threshold, on ``log10`` of the value when ``log``) or ``"finding"`` (a diagnosis
    other than ``none``)."""

    name: str
    column: str
    test: str
    threshold: float
    meaning: str
    log: bool = False


#: the identified parameters the statistical rule scores, and whether on a log scale
SCORED = (("gas_pressure_static_pa", False), ("gas_volume_static_m3", False),
          ("friction_force_n", False),
          *((f"{side}_{name}", name != "smoothing_g")
            for side in ("rebound", "compression")
            for name in ("k_leak", "k_port", "k_spring", "preload_pa", "smoothing_g")))

RULES: tuple[Rule, ...] = (
    Rule("low_gas_charge", "gas_pressure_static_pa", "below_median", 0.85,
         "gas charge below 85 % of the fleet's median: a leaking or under-filled gas "
         "chamber (a charge tolerance is typically ±5 %)"),
    Rule("high_friction", "friction_force_n", "above_median", 1.5,
         "friction above 1.5x the fleet's median: a tight seal or rod guide"),
    Rule("poor_fit", "validation_relative_rms", "above_median", 2.0,
         "validation error above 2x the fleet's median: the model describes this unit "
         "worse than the others"),
    Rule("diagnosed", "diagnosis_family", "finding", 0.0,
         "the diagnosis found an effect the paper's model lacks"),
    *(Rule(f"atypical_{col}", col, "robust_z", ROBUST_Z_LIMIT,
           f"{col} is atypical for the fleet (modified z-score beyond "
           f"{ROBUST_Z_LIMIT:g}{', on a log scale' if log else ''})", log)
      for col, log in SCORED),
)


@dataclass(frozen=True)
class Flag:
    """A rule that fired on one damper."""

    rule: Rule
    value: Any
    #: the fleet's median of the column (``None`` for the diagnosis rule)
    median: float | None
    detail: str


def _numbers(rows: Sequence[dict[str, Any]], column: str) -> np.ndarray:
    vals = [r.get(column) for r in rows]
    return np.array([float(v) for v in vals if isinstance(v, (int, float))
                     and not isinstance(v, bool) and math.isfinite(v)])


def flag_fleet(rows: Sequence[dict[str, Any]]) -> dict[str, list[Flag]]:
    """``{damper id: the flags that fired}`` over the rows whose status is ``ok``."""
    ok = [r for r in rows if r.get("status") == "ok"]
    out: dict[str, list[Flag]] = {r["id"]: [] for r in ok}
    for rule in RULES:
        if rule.test == "finding":
            for r in ok:
                if r.get(rule.column) not in NO_FINDING:
                    effects = r.get("diagnosis_effects") or ""
                    out[r["id"]].append(Flag(rule, r[rule.column], None,
                                             f"{r[rule.column]} ({effects})" if effects
                                             else str(r[rule.column])))
            continue
        values = _numbers(ok, rule.column)
        if values.size < MIN_FLEET:
            continue
        scale = np.log10(values) if rule.log and np.all(values > 0) else values
        median = float(np.median(values))
        centre = float(np.median(scale))
        mad = float(np.median(np.abs(scale - centre)))
        for r in ok:
            v = r.get(rule.column)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                continue
            if rule.test == "below_median" and v < rule.threshold * median:
                out[r["id"]].append(Flag(rule, v, median, f"{v:.4g} < {rule.threshold:g} x "
                                                          f"median {median:.4g}"))
            elif rule.test == "above_median" and v > rule.threshold * median:
                out[r["id"]].append(Flag(rule, v, median, f"{v:.4g} > {rule.threshold:g} x "
                                                          f"median {median:.4g}"))
            elif (rule.test == "robust_z" and mad > 0
                  and abs(v - median) > MIN_RELATIVE_DEVIATION * abs(median)):
                x = math.log10(v) if rule.log and v > 0 else v
                z = MAD_TO_SIGMA * (x - centre) / mad
                if abs(z) > rule.threshold:
                    out[r["id"]].append(Flag(rule, v, median, f"{v:.4g} (median "
                                                              f"{median:.4g}, M = {z:+.1f})"))
    return out
