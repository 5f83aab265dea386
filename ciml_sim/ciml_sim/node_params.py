"""Parameter schema of the mujoco_bridge node (ciml_learning.core.params): the one source of its
declare() calls, config/mujoco_bridge.yaml and the README table."""
from __future__ import annotations

from ciml_learning.core.params import NodeSchema, Param
from ciml_learning.ros.node_params import ROBOT, THREAD_PRIORITY

MUJOCO_BRIDGE = NodeSchema("ciml_sim", "mujoco_bridge",
                           "the simulated robot (MuJoCo, 1 kHz joint loop) on the live graph", (
    Param("scenario", "nominal", "Scenario: a YAML file or a shipped scenario name, written for the robot (its "
          "`robot:` key; another robot's is refused at start) ('' = the robot's own shipped scenario: hyq default_gap, "
          "go1 go1_gap; nominal, for any robot, when it has none)"),
    Param("seed", 0, "Seed of the sensor noise", "", 0, 2**31 - 1),
    Param("publish_rate", 250.0, "Sensor and /clock publish rate (1000/n; physics runs at 1 kHz)", "Hz", 10.0, 1000.0),
    Param("command_timeout", 0.05, "Damping mode after this long without a valid /torque_command (simulation time)",
          "s", 0.004, 5.0, read_only=False),
    Param("damping_gain", 0.0, "Joint damping in damping mode (0 = derived from the robot: 10 Nm s/rad scaled by "
          "its mass, ciml_control.standing.safe_damping_gain)", "Nm s/rad", 0.0, 200.0, read_only=False),
    Param("real_time_factor", 1.0, "Simulation seconds per wall-clock second (the most, with lockstep)", "",
          0.05, 20.0),
    Param("lockstep", False, "Under torque control, publish the next sample only once the command stamped with "
          "the last one has arrived (simulation time waits for the controller: every sample gets its command "
          "on a slow machine); false: free-running against the wall clock, as a real robot"),
    Param("lockstep_timeout", 2.0, "Wall-clock wait for a command in lockstep; then free-running until the next "
          "command (a dead controller still meets command_timeout)", "s", 0.01, 10.0, read_only=False),
    Param("hold_standing_until_command", True, "Hold the standing pose (joint PD + gravity compensation) after start "
          "and reset until the first torque command; false: damp the joints instead"),
    Param("publish_ground_truth", False, "Also publish the simulation-only /sim/ topics (true v̇, contact and "
          "effect forces)", read_only=False),
    THREAD_PRIORITY,
    ROBOT,
))

SCHEMAS: tuple[NodeSchema, ...] = (MUJOCO_BRIDGE,)
