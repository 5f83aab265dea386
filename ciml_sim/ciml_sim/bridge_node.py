"""`mujoco_bridge`: the simulated robot on the live graph (docs/ARCHITECTURE.md §3).

Thin adapter around ciml_sim.plant.Plant (physics and the robot's joint PD loop at 1 kHz). The
robot is the `robot` profile's (URDF, feet, torque limits; built for MuJoCo by ciml_sim.mjcf, as
`ciml record` does); the scenario must be written for it (scenario.scenario_of_robot: '' = the
robot's own shipped scenario).

Timing: Python cannot wake at 1 kHz reliably (docs/ARCHITECTURE.md §10), so a wall timer at the
publish rate (250 Hz) advances the physics by the 1 ms steps owed to wall-clock time
(simulation time follows the wall clock × `real_time_factor`), publishing one sample
per `1000 / publish_rate` steps, always on the same simulation-time grid. A late timer
is caught up (up to 20 ms); beyond that the debt is dropped and counted as an overrun,
so the simulation slows down instead of bursting. The achieved physics rate and the
p99 tick-period error are reported on /diagnostics.

Lockstep (`lockstep`, on in the shipped launch file): under torque control the bridge
publishes the next sample only once the command stamped with the last one has arrived,
so simulation time waits for the controller and every sample gets its own command, as a
controller running inside the simulator's loop does (Gazebo with ros2_control). Without
it, a controller slower than real time on a loaded machine has each command applied for
several samples (the catch-up above) and the robot falls, which is what a real robot
would do; with it, sim time runs at most `real_time_factor` and as fast as the graph
answers (docs/LIVE_GRAPH.md, timing). A controller silent for `lockstep_timeout` wall
seconds releases the lockstep until its next command (counted `lockstep_timeouts`), so
a dead controller still meets `command_timeout` and damping. A sample's base and contact
state are published before its joint state, the controller's trigger.

Topics: /joint_states, /base_state, /contact_state (reliable, depth 10: default-QoS readers match), /clock (sim time),
/diagnostics; optional /sim/ ground truth (`publish_ground_truth`); subscribes
/torque_command (reliable). Service ~/reset (std_srvs/Trigger).

Start-up: after start and after ~/reset the plant stands in its standing pose, and
until the first valid MODE_TORQUE command arrives the bridge *holds* it there with the
standing controller (ciml_control.standing: the joint PD on the standing joint angles
plus gravity compensation with the weight shared by the four feet, computed once on
the nominal model), so a controller that starts late finds the robot standing instead
of collapsed on its trunk. /diagnostics says so (level WARN, message starting
`holding the standing pose:`). With `hold_standing_until_command` false the bridge
damps instead, as a stopped controller's robot does. A MODE_DAMPING command does not
end the hold: it is ignored and counted (damping_ignored_while_holding), since a
controller that has never commanded torque is "not ready yet", not "stopped after
running" (docs/LIVE_GRAPH.md, standing start).

Safety: after `command_timeout` (simulation time) without a valid command once torque
control has started, or on a MODE_DAMPING command, the joints are only damped
(u = −damping_gain·q̇) and /diagnostics says so (level WARN, `damping mode:`): a
controller that stops is not replaced by a posture controller. Commands with non-finite
values, wrong joint names or sizes, or negative gains are dropped and counted; NaN
never reaches the actuators.
"""
from __future__ import annotations

import time
from collections import deque

import numpy as np
from ciml_msgs.msg import ContactState, TorqueCommand
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.publisher import Publisher
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from ciml_control.standing import safe_damping_gain
from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.profile import load_profile
from ciml_learning.ros.ros_common import COMMAND_QOS, OK, SENSOR_PUB_QOS, WARN, Health, declare_schema, run_node

from .node_params import MUJOCO_BRIDGE
from .plant import Plant
from .scenario import scenario_of_robot

MAX_CATCH_UP = 0.02
"""[s] of wall-clock lag the bridge catches up in one tick; more is dropped (an overrun)."""
STATS_WINDOW = 250
"""Tick periods per reported statistic."""


class MujocoBridge(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("mujoco_bridge", **kwargs)
        p = declare_schema(self, MUJOCO_BRIDGE, self._apply_parameters)  # node_params.py: the one schema
        scenario, self.seed, rate = p["scenario"], p["seed"], p["publish_rate"]
        self.timeout, self.rtf = p["command_timeout"], p["real_time_factor"]
        self.hold_at_start, self.publish_truth = p["hold_standing_until_command"], p["publish_ground_truth"]
        self.lockstep, self.lockstep_timeout = p["lockstep"], p["lockstep_timeout"]
        self.profile = load_profile(p["robot"])
        self.robot = self.profile.robot()
        self.kd_safe = p["damping_gain"] or safe_damping_gain(self.robot)  # 0: derived from the robot's size
        self.scenario = scenario_of_robot(scenario, self.profile.name, self.robot)
        self.steps_per_sample = max(1, int(round(1000.0 / rate)))
        self.plant = Plant(self.robot, self.scenario, seed=self.seed)
        self.health = Health(self, "mujoco")
        self.pub_joints = self.create_publisher(JointState, topics.JOINT_STATES, SENSOR_PUB_QOS)
        self.pub_base = self.create_publisher(Odometry, topics.BASE_STATE, SENSOR_PUB_QOS)
        self.pub_contacts = self.create_publisher(ContactState, topics.CONTACT_STATE, SENSOR_PUB_QOS)
        self.pub_clock = self.create_publisher(Clock, topics.CLOCK, 10)
        self._truth_pubs: dict[str, Publisher] = {}
        self.create_subscription(TorqueCommand, topics.TORQUE_COMMAND, self.on_command, COMMAND_QOS)
        self.create_service(Trigger, "~/reset", self.on_reset)
        self.commands_received = 0
        self.damping = self.holding = False
        self._hold_command = self._standing_command()
        self._start_waiting("waiting for the first /torque_command")
        self.last_command_time = -np.inf
        self._published_ns = -1   # stamp of the last published sample
        self._answered_ns = -1    # newest stamp of a valid command
        self._published_wall = 0.0
        self._lockstep_released = False
        self._wall0 = time.monotonic()
        self._steps_done = 0  # physics steps accounted against the wall clock (dropped debt included)
        self.physics_steps = 0  # physics steps actually taken
        self._last_tick: float | None = None
        self.tick_periods: deque[float] = deque(maxlen=20_000)  # wall seconds between ticks (recent)
        self.n_ticks = 0
        self._window_start = (self._wall0, 0)  # (wall time, physics steps) at the window's start
        self.period = self.steps_per_sample * 1e-3 / self.rtf  # [s] wall clock per sample at real_time_factor
        self.create_timer(self.period, self.tick)
        self.get_logger().info(
            f"mujoco_bridge: {self.profile.name} ({self.robot.n_joints} joints), scenario {self.scenario.name}, "
            f"physics 1 kHz, publishing at "
            f"{1000.0 / self.steps_per_sample:g} Hz of simulation time, real-time factor {self.rtf:g}")

    def _apply_parameters(self, changes: dict) -> str | None:
        """Run-time sets of the reconfigurable parameters (the others are read-only)."""
        self.timeout = changes.get("command_timeout", self.timeout)
        self.lockstep_timeout = changes.get("lockstep_timeout", self.lockstep_timeout)
        self.publish_truth = changes.get("publish_ground_truth", self.publish_truth)
        if "damping_gain" in changes:
            self.kd_safe = changes["damping_gain"] or safe_damping_gain(self.robot)
            if self.damping:  # damping now: with the new gain
                self._enter_damping(self.health.mode_message)
        return None

    # --- commands ------------------------------------------------------------------------
    def _standing_command(self):
        """(u_ff, q_t, q̇_t, K_p, K_d) holding the plant's standing pose on all feet."""
        from ciml_control.standing import StandingController

        q0 = self.plant.standing_configuration()
        c = StandingController(self.robot).compute(q0, np.ones(self.robot.n_feet, dtype=bool))
        return (c.feedforward + c.feedback_linearization, c.q_target, c.qd_target, c.kp, c.kd)

    def _start_waiting(self, why: str) -> None:
        """After start or reset: hold the standing pose (or damp) until a torque command."""
        if self.hold_at_start:
            self.plant.set_command(*self._hold_command)
            self.damping, self.holding = False, True
            self.health.set(WARN, f"holding the standing pose: {why}")
            self.health.counts["damping_mode"] = 0
            self.health.counts["holding_standing_pose"] = 1
        else:
            self._enter_damping(f"damping mode: {why}")

    def _enter_damping(self, why: str) -> None:
        n = self.robot.n_joints
        z = np.zeros(n)
        self.plant.set_command(z, z, z, z, np.full(n, self.kd_safe), damping_mode=True)
        self.damping, self.holding = True, False
        self.health.set(WARN, why)
        self.health.counts["damping_mode"] = 1
        self.health.counts["holding_standing_pose"] = 0

    def on_command(self, msg: TorqueCommand) -> None:
        try:
            cmd = cv.torque_command_arrays(self.robot, msg)
            if cmd.mode not in (TorqueCommand.MODE_TORQUE, TorqueCommand.MODE_DAMPING):
                raise cv.ConversionError(f"torque_command: unknown mode {cmd.mode}")
            if cmd.mode == TorqueCommand.MODE_TORQUE:
                # the position target moves along the velocity target from the header stamp
                self.plant.set_command(cmd.feedforward + cmd.feedback_linearization, cmd.position_target,
                                       cmd.velocity_target, cmd.stiffness, cmd.damping,
                                       stamp=cv.stamp_to_ns(msg.header.stamp) * 1e-9)
        except CimlError as err:  # ConversionError, RobotDescriptionError (joint names), PlantError
            self.health.count("rejected_commands", f"command rejected: {err}")  # WARN while they keep coming
            return
        self.commands_received += 1
        self.health.counts["commands_received"] = self.commands_received
        self._answered_ns = max(self._answered_ns, cv.stamp_to_ns(msg.header.stamp))
        self._lockstep_released = False
        self.last_command_time = self.plant.time
        if cmd.mode == TorqueCommand.MODE_DAMPING:
            if self.holding:
                # "not ready yet" is not "stopped after running": a controller that has never
                # commanded torque since the start (or reset) cannot end the standing hold
                self.health.counts["damping_ignored_while_holding"] += 1
            elif not self.damping:
                self._enter_damping("damping mode: requested by /torque_command")
        elif self.damping or self.holding:
            self.damping = self.holding = False
            self.health.counts["damping_mode"] = 0
            self.health.counts["holding_standing_pose"] = 0
            self.health.set(OK, "torque control")
        if self.lockstep and not (self.holding or self.damping) and self._answered_ns >= self._published_ns:
            now = time.monotonic()
            if now - self._published_wall >= self.period:  # the sample is due: no wait for the next tick
                self._lockstep_tick(now)

    def on_reset(self, request, response):
        t = self.plant.time
        self.plant.reset()
        self.plant.set_time(t)  # keep /clock monotonic
        self.last_command_time = -np.inf
        self._start_waiting("reset, waiting for /torque_command")
        self.health.count("resets")
        response.success = True
        response.message = ("plant reset to the standing pose; "
                            + ("held there" if self.holding else "joints damped") + " until the next command")
        return response

    # --- the loop ----------------------------------------------------------------------------
    def tick(self) -> None:
        now = time.monotonic()
        if self._last_tick is not None:
            self.tick_periods.append(now - self._last_tick)
            self.n_ticks += 1
        self._last_tick = now
        if self.lockstep and not (self.holding or self.damping):
            self._lockstep_tick(now)
            self._stats(now)
            return
        owed = int((now - self._wall0) * 1000.0 * self.rtf) - self._steps_done
        max_steps = int(MAX_CATCH_UP * 1000.0) + self.steps_per_sample
        if owed > max_steps:
            self.health.count("realtime_overruns")
            self._steps_done += owed - max_steps  # drop the debt: simulation time slows down
            owed = max_steps
        if self._samples(owed // self.steps_per_sample):
            self._stats(now)

    def _lockstep_tick(self, now: float) -> None:
        """One sample per tick, once the last one's command has arrived (or the wait timed out)."""
        if self._answered_ns < self._published_ns and not self._lockstep_released:
            if now - self._published_wall < self.lockstep_timeout:
                self.health.counts["lockstep_waits"] += 1
                return
            self._lockstep_released = True  # free-running until the next command
            self.health.count("lockstep_timeouts", f"no command within {self.lockstep_timeout:g} s: free-running")
        if self._samples(1):
            self._steps_done = int((now - self._wall0) * 1000.0 * self.rtf)  # no debt when the lockstep ends

    def _samples(self, n: int) -> bool:
        """Take and publish n samples; False if a signal shut the context down meanwhile."""
        try:
            for _ in range(n):
                self._sample()
        except Exception:
            if self.context.ok():
                raise
            return False  # SIGTERM/SIGINT shut the context down during this tick: normal shutdown
        return True

    def _sample(self) -> None:
        if not (self.damping or self.holding) and self.plant.time - self.last_command_time > self.timeout:
            self.health.count("stale_command_damping")
            self._enter_damping(f"damping mode: no valid /torque_command for {self.timeout:g} s")
        self.plant.step(self.steps_per_sample)
        self._steps_done += self.steps_per_sample
        self.physics_steps += self.steps_per_sample
        m = self.plant.measure()
        ns = int(round(m.time * 1e9))
        self.pub_clock.publish(Clock(clock=cv.stamp_msg(ns)))
        self.pub_base.publish(cv.odometry_msg(ns, m.base_position, m.base_orientation, m.base_linear_velocity,
                                              m.base_angular_velocity))
        self.pub_contacts.publish(cv.contact_state_msg(self.robot, ns, m.contacts))
        self._published_ns, self._published_wall = ns, time.monotonic()
        self.pub_joints.publish(cv.joint_state_msg(self.robot, ns, m.q, m.qd, m.tau_measured))  # the trigger: last
        if self.publish_truth:
            from ciml_msgs.msg import ContactForces, GeneralizedForce

            from .recorder import ground_truth_messages

            for topic, msg in ground_truth_messages(self.robot, ns, self.plant.ground_truth()):
                pub = self._truth_pubs.get(topic)
                if pub is None:
                    cls = ContactForces if topic == topics.SIM_CONTACT_FORCES else GeneralizedForce
                    pub = self._truth_pubs[topic] = self.create_publisher(cls, topic, 10)
                pub.publish(msg)

    def _stats(self, now: float) -> None:
        w0, s0 = self._window_start
        if self.n_ticks % STATS_WINDOW or not self.n_ticks:
            return
        p = np.asarray(list(self.tick_periods)[-STATS_WINDOW:])
        nominal = self.steps_per_sample * 1e-3 / self.rtf
        c = self.health.counts
        c["achieved_physics_rate_hz"] = round((self.physics_steps - s0) / (now - w0), 1)
        c["tick_period_error_p99_ms"] = round(1e3 * float(np.percentile(np.abs(p - nominal), 99)), 3)
        c["sim_time_s"] = round(self.plant.time, 3)
        self._window_start = (now, self.physics_steps)


def main(args=None) -> None:
    import sys

    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.exceptions import InvalidParameterValueException

    try:
        run_node(MujocoBridge, args)
    except (CimlError, InvalidParameterValueException) as err:  # bad scenario, URDF or parameter
        print(f"mujoco_bridge: error: {' '.join(str(err).split())}", file=sys.stderr)
        sys.exit(1)
    except RCLError as err:
        # rclpy race on SIGTERM: the signal handler shuts the context down while spin()
        # builds its wait set; that is a normal shutdown, anything else is not
        if "context is not valid" not in str(err):
            raise
