"""damper-hil: real-time hardware-in-the-loop damper emulator."""

__version__ = "0.1.0"
