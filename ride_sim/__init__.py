"""Quarter-car ride simulation (issue 4): physics only, no ROS imports."""
