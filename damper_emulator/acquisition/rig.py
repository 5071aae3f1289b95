"""The rig's data sheet: one acquisition channel per measured quantity (``--rig FILE``).

A rig file holds a ``rig`` group (at the top level, or under a node's ``ros__parameters``)
with one sub-group per channel::

    rig:
      force:                 # load cell → amplifier → DAQ
        filter: butterworth
        order: 2
        cutoff_hz: 200.0
        adc_bits: 12
        full_scale_n: 10000.0
      displacement:          # LVDT → conditioner → DAQ
        filter: none

Every key has a default (a channel that does nothing), so a file names only what its rig
does.  The sample rate is each file's own (its time column); the schema is listed in
docs/parameters.md (``rig.force``, ``rig.displacement``) and explained in docs/diagnose.md
("The measurement chain").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, TypeVar

import yaml

from damper_emulator.schema import (
    ParameterError,
    build_group,
    check_value,
    node_parameters,
    read_yaml,
    rule,
)

#: the analog filters a channel may have (``none``: the channel passes its signal as is)
FILTER_TYPES = ("none", "butterworth", "bessel")
#: the largest filter order the schema accepts (a DAQ's anti-alias filters go to 8)
MAX_FILTER_ORDER = 8
#: the largest converter resolution [bit]
MAX_ADC_BITS = 24
#: the largest skew between a channel and the DAQ's clock [s]
MAX_SKEW_S = 0.1
#: the largest zero offset [N] (and drift [N/s]) of a force channel's schema
MAX_ZERO_N = 1e6


@dataclass(frozen=True)
class Channel:
    """What one channel of the rig does to its signal, in order: an analog low-pass
    filter, a delay against the DAQ's clock, sampling, an analog-to-digital converter."""

    filter: str = rule(("choices", FILTER_TYPES),
                       "the analog low-pass filter: none, butterworth or bessel (the "
                       "amplifier's and the DAQ's anti-alias filter, as one)", "none")
    order: int = rule(("int_range", 1, MAX_FILTER_ORDER),
                      "the filter's order (its number of poles) [-]", 2)
    cutoff_hz: float = rule("positive",
                            "the filter's −3 dB frequency [Hz] (a Bessel filter too: "
                            "scipy's norm='mag')", 1000.0)
    adc_bits: int = rule(("int_range", 0, MAX_ADC_BITS),
                         "the converter's resolution [bit] (0: not quantised)", 0)
    skew_s: float = rule(("closed", -MAX_SKEW_S, MAX_SKEW_S),
                         "the channel's delay against the DAQ's clock [s] (positive: the "
                         "sample stamped t holds the signal of t − skew)", 0.0)

    @property
    def filtered(self) -> bool:
        return self.filter != "none"

    @property
    def full_scale(self) -> float:
        """The converter's range (± this, in the channel's unit)."""
        raise NotImplementedError  # each channel's own field

    @property
    def adc_step(self) -> float:
        """One step of the converter, ``2 full_scale / 2^bits`` (0: not quantised)."""
        return 2.0 * self.full_scale / 2.0 ** self.adc_bits if self.adc_bits else 0.0


@dataclass(frozen=True)
class ForceChannel(Channel):
    """The force channel: load cell, amplifier, DAQ."""

    full_scale_n: float = rule("positive",
                               "the converter's range, ± this [N] (with adc_bits: one "
                               "step is 2 full_scale / 2^bits)", 20_000.0)
    gain: float = rule("positive", "the channel's gain against its calibration: it records "
                                   "gain × the force [-]", 1.0)
    zero_offset_n: float = rule(("closed", -MAX_ZERO_N, MAX_ZERO_N),
                                "the load cell's zero: what it records at no force, at "
                                "each file's first sample [N]", 0.0)
    zero_drift_n_per_s: float = rule(("closed", -MAX_ZERO_N, MAX_ZERO_N),
                                     "the zero's drift within each file [N/s]", 0.0)

    @property
    def full_scale(self) -> float:
        return self.full_scale_n

    @property
    def scales(self) -> bool:
        """Whether the channel's gain or zero is off its calibration."""
        return (self.gain != 1.0 or self.zero_offset_n != 0.0
                or self.zero_drift_n_per_s != 0.0)


@dataclass(frozen=True)
class DisplacementChannel(Channel):
    """The displacement channel: LVDT or encoder, conditioner, DAQ.

    A velocity channel derived from it shares its filter."""

    full_scale_m: float = rule("positive",
                               "the converter's range, ± this [m] (with adc_bits: one "
                               "step is 2 full_scale / 2^bits)", 0.25)

    @property
    def full_scale(self) -> float:
        return self.full_scale_m


@dataclass(frozen=True)
class RigParams:
    """The rig's acquisition chain: one channel per measured quantity."""

    force: ForceChannel = field(default_factory=ForceChannel)
    displacement: DisplacementChannel = field(default_factory=DisplacementChannel)

    @property
    def does_nothing(self) -> bool:
        """No filter, no skew, the force's gain and zero calibrated: the model's force is
        compared as it is."""
        return not (any(ch.filtered or ch.skew_s != 0.0
                        for ch in (self.force, self.displacement)) or self.force.scales)


_C = TypeVar("_C", bound=Channel)

#: the channel groups of a ``rig`` group, by key
CHANNELS: dict[str, type[Channel]] = {"force": ForceChannel,
                                       "displacement": DisplacementChannel}


def rig_from_mapping(doc: Any, where: str = "<memory>") -> RigParams:
    """The :class:`RigParams` of a parsed rig file (module docstring).

    Raises
    ------
    ParameterError
        One line naming ``where`` and the key: an unknown key or a value out of its rule.
    """
    group = node_parameters(doc, where, "rig")["rig"]
    if group is None:
        return RigParams()
    if not isinstance(group, Mapping):
        raise ParameterError(f"{where}: rig must be a mapping of channels "
                             f"({', '.join(CHANNELS)})")
    unknown = sorted(set(group) - set(CHANNELS), key=str)
    if unknown:
        raise ParameterError(f"{where}: unknown channel rig.{unknown[0]} (one of "
                             f"{', '.join(CHANNELS)})")
    def channel(name: str, cls: type[_C]) -> _C:
        return build_group(cls, group.get(name) or {}, f"rig.{name}", where, check_value)

    return RigParams(force=channel("force", ForceChannel),
                     displacement=channel("displacement", DisplacementChannel))


def load_rig(path: str | Path) -> RigParams:
    """The rig file at ``path`` (:func:`rig_from_mapping`); one-line error when it cannot be
    read."""
    return rig_from_mapping(read_yaml(path), str(path))


def rig_to_mapping(rig: RigParams) -> dict[str, Any]:
    """``{"rig": {channel: {key: value}}}``: a rig file's content (and the JSON's
    ``acquisition.rig``)."""
    return {"rig": {name: {f.name: getattr(getattr(rig, name), f.name)
                           for f in fields(getattr(rig, name))}
                    for name in CHANNELS}}


def save_rig(rig: RigParams, path: str | Path, comment: str = "") -> None:
    """Write ``rig`` as a rig file (:func:`load_rig` reads it back), under ``comment``
    (``#`` lines)."""
    head = "".join(f"# {line}\n" if line else "#\n" for line in comment.splitlines())
    Path(path).write_text(head + yaml.safe_dump(rig_to_mapping(rig), sort_keys=False))


def with_channel(rig: RigParams, name: str, **changes: Any) -> RigParams:
    """``rig`` with channel ``name`` changed by ``changes``."""
    return dataclasses.replace(rig, **{name: dataclasses.replace(getattr(rig, name),
                                                                 **changes)})
