"""CIML simulation: MuJoCo stand-in for the robot with configurable unmodelled effects."""
import os

from ciml_learning import quiet_interrupt_while_starting

# CIML never renders. Unless told otherwise, importing mujoco loads GLFW, which probes its library
# in a child Python process: ~0.1 s of every bridge start, and a Ctrl-C during it left that child
# writing to a closed pipe (a BrokenPipeError traceback in the bridge's output, exit status 0).
os.environ.setdefault("MUJOCO_GL", "disable")

quiet_interrupt_while_starting(("mujoco_bridge",))
