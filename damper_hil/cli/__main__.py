"""``python -m damper_hil.cli``."""

from damper_hil.cli import entry

entry()
