"""The application layer of damper-hil: the command line (:mod:`damper_hil.cli`), the
closed-loop demo (:mod:`damper_hil.hil_demo`) and its report.  The only package that knows
every other one: ``damper_emulator`` (the damper: model, identification, diagnosis,
emulator, bags), ``ride_sim`` (the quarter car) and ``can_bridge`` (the CAN side) never
import it."""

from damper_emulator import __version__

__all__ = ["__version__"]
