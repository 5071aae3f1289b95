"""Diagnosis of the model's residual against measured data: which effect the model lacks.

* :mod:`.residual`: the per-sample residual of a model on a measured record and its
  features (friction, drift, stiffness, harmonics);
* :mod:`.candidates`: the library's effects as candidate extensions;
* :mod:`.joint`: the joint fit of a candidate with the base parameters;
* :mod:`.selection`: forward selection with held-out data, the answer by family;
* :mod:`.discovery`: a term outside the library, by sparse regression on the residual;
* :mod:`.truth`: truth data of another model form through a rig's acquisition chain;
* :mod:`.report`: the report.
"""

from damper_emulator.diagnose.residual import (
                                               ResidualRecord,
                                               plot_residual,
                                               residual_features,
                                               residual_record,
)

__all__ = ["ResidualRecord", "plot_residual", "residual_features", "residual_record"]
