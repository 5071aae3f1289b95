"""CAN bridge between the emulator and a CAN dyno or adaptive-damper controller (issue 6)."""
