"""Typed parameters of every managed (lifecycle) node: the emulator and the CAN bridge.

Declared by :class:`damper_emulator.ros.managed.ManagedNode` from this schema, beside each
node's own group, and listed in docs/parameters.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from damper_emulator.schema import rule


@dataclass(frozen=True)
class ManagedNodeParams:
    """The lifecycle of a managed node."""

    autostart: bool = rule("bool", "configure and activate at start (false: stay "
                                   "unconfigured and wait for a lifecycle manager's "
                                   "transitions)", True)
