"""`mujoco_bridge`: the simulated robot on the live graph (DESIGN.md §3).

Thin adapter around ciml_sim.plant.Plant: physics at 1 kHz with the joint PD loop
inside the plant; sensors and /clock published at `publish_rate` in simulation time.
Python cannot promise 1 kHz wall-clock timing (ROS_WHEELS.md), so a wall timer at
the publish rate advances the physics by the matching number of 1 ms steps; the
achieved rate and period jitter are reported on /diagnostics.

Safety: a command older than `command_timeout` (sim time) or never received puts the
joints in damping mode; non-finite or mismatched commands are rejected and counted.
"""
from __future__ import annotations

import time

import numpy as np
from ciml_msgs.msg import ContactState, TorqueCommand
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from ciml_learning import conversions as cv
from ciml_learning import topics
from ciml_learning.errors import CimlError
from ciml_learning.robot import load_robot
from ciml_learning.ros_common import COMMAND_QOS, SENSOR_QOS, Health, declare, run_node

from .plant import Plant
from .scenario import load_scenario, nominal_scenario


class MujocoBridge(Node):
    def __init__(self) -> None:
        super().__init__("mujoco_bridge")
        scenario_path = declare(self, "scenario", "", "Scenario YAML with the unmodelled effects ('' = nominal)")
        self.seed = declare(self, "seed", 0, "Random seed of sensor noise", 0, 2**31 - 1)
        rate = declare(self, "publish_rate", 250.0, "Sensor and /clock publish rate [Hz]", 50.0, 1000.0)
        self.timeout = declare(self, "command_timeout", 0.05, "Damping mode after this long without a command [s]", 0.004, 5.0)
        self.kd_safe = declare(self, "damping_gain", 10.0, "Joint damping in the safe mode [Nm s/rad]", 0.0, 200.0)
        urdf = declare(self, "urdf", "", "Robot URDF ('' = HyQ from example-robot-data)")
        self.robot = load_robot(urdf or None)
        self.scenario = load_scenario(scenario_path, self.robot) if scenario_path else nominal_scenario()
        self.steps_per_tick = max(1, int(round(1000.0 / rate)))
        self.plant = Plant(self.robot, self.scenario, seed=self.seed)
        self.plant.reset()
        self.health = Health(self, "mujoco")
        self.pub_joints = self.create_publisher(JointState, topics.JOINT_STATES, SENSOR_QOS)
        self.pub_base = self.create_publisher(Odometry, topics.BASE_STATE, SENSOR_QOS)
        self.pub_contacts = self.create_publisher(ContactState, topics.CONTACT_STATE, SENSOR_QOS)
        self.pub_clock = self.create_publisher(Clock, topics.CLOCK, 10)
        self.create_subscription(TorqueCommand, topics.TORQUE_COMMAND, self.on_command, COMMAND_QOS)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.last_command_time = -np.inf
        self.damping = True
        self._apply_damping()
        self._last_wall = None
        self._periods: list[float] = []
        self.create_timer(self.steps_per_tick * 1e-3, self.tick)

    def _apply_damping(self) -> None:
        n = self.robot.n_joints
        z = np.zeros(n)
        self.plant.set_command(z, z, z, z, np.full(n, self.kd_safe), damping_mode=True)

    def on_command(self, msg) -> None:
        try:
            cmd = cv.torque_command_arrays(self.robot, msg)
        except CimlError as err:  # ConversionError, or RobotDescriptionError for wrong joint names
            self.health.count("rejected_commands", f"command rejected: {err}")
            return
        if cmd.mode == 1:
            self.damping = True
            self._apply_damping()
        else:
            self.damping = False
            self.plant.set_command(cmd.feedforward + cmd.feedback_linearization, cmd.position_target,
                                   cmd.velocity_target, cmd.stiffness, cmd.damping)
        self.last_command_time = self.plant.time

    def on_reset(self, request, response):
        self.plant.reset()
        self.last_command_time = -np.inf
        self._apply_damping()
        response.success = True
        response.message = "plant reset to the standing pose; joints damped until the next command"
        return response

    def tick(self) -> None:
        wall = time.monotonic()
        if self._last_wall is not None:
            self._periods.append(wall - self._last_wall)
            if len(self._periods) >= 250:
                p = np.asarray(self._periods)
                # physics steps per wall second: 1 kHz is held when this is ~1000
                self.health.counts["achieved_physics_rate_hz"] = round(self.steps_per_tick / p.mean(), 1)
                self.health.counts["tick_period_error_p99_ms"] = round(1e3 * np.percentile(np.abs(p - self.steps_per_tick * 1e-3), 99), 3)
                self._periods.clear()
        self._last_wall = wall
        if self.plant.time - self.last_command_time > self.timeout and not self.damping:
            self.damping = True
            self._apply_damping()
            self.health.count("stale_command_damping", "no command within the timeout: joints damped")
        self.plant.step(self.steps_per_tick)
        m = self.plant.measure()
        ns = int(round(m.time * 1e9))
        self.pub_clock.publish(Clock(clock=cv.stamp_msg(ns)))
        self.pub_joints.publish(cv.joint_state_msg(self.robot, ns, m.q, m.qd, m.tau_measured))
        self.pub_base.publish(cv.odometry_msg(ns, m.base_position, m.base_orientation, m.base_linear_velocity, m.base_angular_velocity))
        self.pub_contacts.publish(cv.contact_state_msg(self.robot, ns, m.contacts))
        if not self.damping:
            self.health.set(0, "ok")


def main(args=None) -> None:
    run_node(MujocoBridge, args)
