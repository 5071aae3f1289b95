"""The rig's measurement chain: what the dyno's acquisition does to a signal before it is
a sample in a file (analog filters, channel skew, sampling, quantisation), as a model
the damper's force passes through before it is compared with measured data.

:mod:`.rig` is the data-sheet schema (``--rig``), :mod:`.chain` the filters and delays.
Core layer: imports nothing above :mod:`damper_emulator.params`.
"""

from damper_emulator.acquisition.chain import (
    AcquisitionError,
    dc_group_delay,
    model_record,
    record_channel,
)
from damper_emulator.acquisition.rig import (
    DisplacementChannel,
    ForceChannel,
    RigParams,
    load_rig,
    rig_from_mapping,
    rig_to_mapping,
    save_rig,
)

__all__ = ["AcquisitionError", "DisplacementChannel", "ForceChannel", "RigParams",
           "dc_group_delay", "load_rig", "model_record", "record_channel",
           "rig_from_mapping", "rig_to_mapping", "save_rig"]
