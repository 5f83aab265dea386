"""CIML simulation: MuJoCo stand-in for the robot with configurable unmodelled effects."""
