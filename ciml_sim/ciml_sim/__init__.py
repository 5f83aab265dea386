"""CIML simulation: MuJoCo stand-in for the robot with configurable unmodelled effects."""
from ciml_learning import quiet_interrupt_while_starting

quiet_interrupt_while_starting(("mujoco_bridge",))
