"""The damper physics core (numpy/scipy/numba only, never rclpy)."""
