"""Diagnosis of the model's residual against measured data (issue 7).

:mod:`damper_emulator.diagnose.residual`: the per-sample residual of a model on a measured
record and the features that trace it to an effect (friction, drift, stiffness, harmonics).
"""

from damper_emulator.diagnose.residual import (
                                               ResidualRecord,
                                               plot_residual,
                                               residual_features,
                                               residual_record,
)

__all__ = ["ResidualRecord", "plot_residual", "residual_features", "residual_record"]
