"""The mujoco_bridge node on the live graph: topics, standing hold until the first command,
damping when commands stop, rejected commands."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from rosutil import Listener, start_node, stop

from ciml_learning.core.robot import load_robot

ROBOT = load_robot()


class _Graph(Listener):
    """Listener with the bridge's QoS, plus a command publisher and a reset client."""

    def __init__(self) -> None:
        from ciml_msgs.msg import ContactState, TorqueCommand
        from diagnostic_msgs.msg import DiagnosticArray
        from nav_msgs.msg import Odometry
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_srvs.srv import Trigger

        from ciml_learning.ros.ros_common import COMMAND_QOS, SENSOR_QOS

        sensors = {"/joint_states": JointState, "/base_state": Odometry, "/contact_state": ContactState}
        super().__init__({**sensors, "/clock": Clock, "/diagnostics": DiagnosticArray},
                         qos={topic: SENSOR_QOS for topic in sensors})
        self.commands = self.node.create_publisher(TorqueCommand, "/torque_command", COMMAND_QOS)
        self.reset = self.node.create_client(Trigger, "/mujoco_bridge/reset")

    def get(self, topic: str) -> list:
        return list(self.messages[topic])  # a snapshot: the spinning thread appends

    def bridge_status(self) -> list:
        return [s for m in self.get("/diagnostics") for s in m.status if "mujoco_bridge" in s.name]


def _values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _standing_height() -> float:
    from ciml_sim.plant import Plant
    from ciml_sim.scenario import nominal_scenario

    return float(Plant(ROBOT, nominal_scenario()).standing_configuration()[2])


def _command(valid: bool = True):
    from ciml_control.standing import StandingController
    from ciml_learning.core import conversions as cv
    from ciml_sim.plant import Plant
    from ciml_sim.scenario import nominal_scenario

    q0 = Plant(ROBOT, nominal_scenario()).standing_configuration()
    c = StandingController(ROBOT).compute(q0, np.ones(ROBOT.n_feet, dtype=bool))
    ff = c.feedforward.copy()
    if not valid:
        ff[3] = math.nan
    return cv.torque_command_msg(ROBOT, 0, cv.TorqueCommandArrays(0, ff, c.feedback_linearization, c.q_target,
                                                                 c.qd_target, c.kp, c.kd))


@pytest.mark.ros
def test_bridge_publishes_damps_without_commands_and_rejects_nan():
    from std_srvs.srv import Trigger

    graph = _Graph()
    proc = start_node("mujoco_bridge")
    log = ""
    try:
        # 1. the documented topics, on one 4 ms simulation-time grid
        assert graph.wait_for(lambda: all(len(graph.get(t)) >= 50 for t in
                                          ("/joint_states", "/base_state", "/contact_state", "/clock")), 30)
        js = graph.get("/joint_states")[-40:]
        assert list(js[0].name) == list(ROBOT.joint_names) and len(js[0].effort) == ROBOT.n_joints
        stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in js])
        assert np.all(np.diff(stamps) > 0) and np.all(np.diff(stamps) % 4_000_000 == 0)
        assert graph.get("/base_state")[-1].child_frame_id == "base"
        assert list(graph.get("/contact_state")[-1].foot_names) == list(ROBOT.foot_frames)
        clock = graph.get("/clock")[-1].clock
        assert clock.sec * 10**9 + clock.nanosec >= stamps[0]

        # 2. no command yet: the bridge holds the standing pose (not damping), and /diagnostics
        #    says so; the base stays at the standing height (pure damping drops it to ~0.27 m)
        assert graph.wait_for(lambda: any(s.level == b"\x01" and "holding the standing pose" in s.message
                                          for s in graph.bridge_status()), 10)
        assert graph.wait_for(lambda: len(graph.get("/base_state")) >= 300, 30)  # ≥ 1.2 s of simulation
        z_stand = _standing_height()
        z = np.array([m.pose.pose.position.z for m in graph.get("/base_state")])
        assert np.all(np.abs(z - z_stand) < 0.02), (z.min(), z.max(), z_stand)
        assert not any("damping" in s.message for s in graph.bridge_status())

        # 3. a NaN command is rejected and counted; the robot keeps standing
        assert graph.wait_for(lambda: graph.node.count_subscribers("/torque_command") >= 1, 10)
        for _ in range(3):
            graph.commands.publish(_command(valid=False))
            time.sleep(0.05)
        assert graph.wait_for(lambda: any(int(_values(s).get("rejected_commands", 0)) >= 3
                                          and "holding the standing pose" in s.message
                                          for s in graph.bridge_status()), 10)
        assert abs(graph.get("/base_state")[-1].pose.pose.position.z - z_stand) < 0.02

        # 4. valid commands: torque control (level OK); when they stop, damping again after the timeout
        n_before = len(graph.bridge_status())
        end = time.monotonic() + 2.5
        while time.monotonic() < end:
            graph.commands.publish(_command())
            time.sleep(0.01)
        recent = graph.bridge_status()[n_before:]
        assert any(s.level == b"\x00" and s.message == "torque control" for s in recent), [s.message for s in recent]
        assert graph.wait_for(lambda: any(int(_values(s).get("stale_command_damping", 0)) >= 1
                                          and "damping" in s.message for s in graph.bridge_status()), 10)
        # damped joints let the robot sink towards its trunk within 1 s of simulation; nothing
        # explodes. (Read 1 s after damping began, not at once: if this thread stalled while it
        # published, the bridge damped mid-stream and the resumed PD command launched the sunk
        # robot up to ~0.97 m, a leap the bridge simulates faithfully — fresh-clone CI, c90ab24.)
        n_damped = len(graph.get("/base_state"))
        assert graph.wait_for(lambda: len(graph.get("/base_state")) >= n_damped + 250, 10)
        z = graph.get("/base_state")[-1].pose.pose.position.z
        assert 0.05 < z < z_stand - 0.1, (z, [int(_values(s).get("stale_command_damping", 0))
                                              for s in graph.bridge_status()[-1:]])

        # 5. reset service
        assert graph.reset.wait_for_service(timeout_sec=5)
        future = graph.reset.call_async(Trigger.Request())
        assert graph.wait_for(future.done, 10) and future.result().success
    finally:
        log = stop(proc)
        graph.close()
    assert "Traceback" not in log, log


@pytest.mark.ros
def test_bridge_command_handling_in_process():
    """The node's command path without the graph: before the first command the standing pose
    is held (no timeout applies); NaN, wrong joint names, negative gains and unknown modes
    are dropped and counted; a valid command starts torque control; a stale one enters
    damping mode after command_timeout of simulation time; damping mode is a request too;
    a reset holds the standing pose again."""
    import random

    import rclpy
    from ciml_msgs.msg import TorqueCommand
    from rclpy.parameter import Parameter

    from ciml_sim.bridge_node import MujocoBridge

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(1, 101))
    try:
        node = MujocoBridge(context=ctx, parameter_overrides=[Parameter("command_timeout", value=0.02)])
        assert node.holding and not node.damping and not node.plant.damping_mode
        assert "holding the standing pose" in node.health.message and node.health.level == 1
        z_stand = float(node.plant.standing_configuration()[2])
        for _ in range(250):  # 1 s of simulation time without a command: no timeout, still standing
            node._sample()
        assert node.holding and not node.damping and "stale_command_damping" not in node.health.counts
        assert abs(node.plant.data.qpos[2] - z_stand) < 0.01
        bad = [_command(valid=False), _command(), _command(), _command()]
        bad[1].joint_names = [n.replace("lf_", "xx_") for n in bad[1].joint_names]
        bad[2].damping = [-1.0] * ROBOT.n_joints
        bad[3].mode = 7
        for msg in bad:
            node.on_command(msg)
        assert node.health.counts["rejected_commands"] == 4 and node.holding and node.commands_received == 0
        node.on_command(_command())
        assert not node.damping and not node.holding and not node.plant.damping_mode and node.health.mode_level == 0
        # the rejections just now stay a WARN condition for a moment, then the level is the mode's (OK)
        assert node.health.level == 1 and "command rejected" in node.health.message
        node.health.event_hold = 0.0
        assert node.health.level == 0 and node.health.message == "torque control"
        for _ in range(3):
            node._sample()  # 12 ms of simulation time: within the timeout
        assert not node.damping
        for _ in range(4):  # past the timeout (not on its edge: simulation time is a float sum of 1 ms steps)
            node._sample()
        assert node.damping and node.health.counts["stale_command_damping"] == 1
        assert "damping mode" in node.health.message and node.health.level == 1
        node.on_command(_command())
        damp = _command()
        damp.mode = TorqueCommand.MODE_DAMPING
        node.on_command(damp)
        assert node.damping and "requested" in node.health.message
        m = node.plant.measure()
        assert np.all(np.isfinite(m.tau_measured))
        response = node.on_reset(None, type("Response", (), {})())
        assert response.success and node.holding and not node.damping and not node.plant.damping_mode
        assert node.health.counts["resets"] == 1 and "holding the standing pose" in node.health.message
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_lockstep_waits_for_each_samples_command_then_releases_a_silent_controller():
    """lockstep:=true: under torque control each sample waits for the command stamped with the
    previous one; a controller that answers every sample gets one command per sample; one that
    goes silent stalls simulated time for lockstep_timeout, then the bridge runs free and damps."""
    from ciml_learning.core import conversions as cv

    graph = _Graph()
    answered: list[int] = []

    def answer(msg) -> None:  # a controller: one command per joint sample, stamped with it
        if graph.answering:
            cmd = _command()
            cmd.header.stamp = msg.header.stamp
            graph.commands.publish(cmd)
            answered.append(cv.stamp_to_ns(msg.header.stamp))

    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    graph.answering = False
    graph.node.create_subscription(JointState, "/joint_states", answer,
                                   QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    proc = start_node("mujoco_bridge", "-p", "lockstep:=true", "-p", "lockstep_timeout:=1.0",
                      "-p", "command_timeout:=0.1")
    log = ""
    try:
        assert graph.wait_for(lambda: len(graph.get("/joint_states")) >= 20, 30)  # holding: free-running
        graph.answering = True
        assert graph.wait_for(lambda: len(answered) >= 400, 60)
        graph.answering = False
        n_answered = len(answered)
        # every sample after the first command was answered before the next one came: no gaps
        stamps = np.array(answered[-300:])
        assert np.all(np.diff(stamps) == 4_000_000), np.unique(np.diff(stamps))
        # silent controller: simulated time stands still for lockstep_timeout (1 s wall) ...
        t_silent = time.monotonic()
        clock0 = cv.stamp_to_ns(graph.get("/clock")[-1].clock)
        time.sleep(0.6)
        assert cv.stamp_to_ns(graph.get("/clock")[-1].clock) - clock0 <= 8_000_000
        # ... then the bridge runs free, meets command_timeout and damps, and says so
        assert graph.wait_for(lambda: any(s.message.startswith("damping mode") for s in graph.bridge_status()), 30)
        values = _values(graph.bridge_status()[-1])
        assert int(values["lockstep_timeouts"]) >= 1 and int(values["lockstep_waits"]) >= 1
        assert time.monotonic() - t_silent >= 1.0
        assert n_answered >= 400
    finally:
        log = stop(proc)
        graph.close()
    assert "Traceback" not in log, log


@pytest.mark.ros
def test_bridge_simulates_the_robot_parameter_and_refuses_another_robots_scenario():
    """robot:=go1 builds go1 (joints, feet, limits of its profile) with its own scenario ('' =
    go1_gap) and a damping gain scaled to its size; a scenario written for another robot, or an
    unknown robot, stops the node at start with one line and exit status 1."""
    import random
    import subprocess

    import rclpy
    from rclpy.parameter import Parameter

    from ciml_learning.core.profile import load_profile
    from ciml_sim.bridge_node import MujocoBridge

    go1 = load_profile("go1").robot()
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(1, 101))
    try:
        node = MujocoBridge(context=ctx, parameter_overrides=[Parameter("robot", value="go1"),
                                                               Parameter("scenario", value="")])
        assert node.robot.joint_names == go1.joint_names and node.robot.foot_frames == go1.foot_frames
        assert node.scenario.name == "go1_gap" and node.scenario.robot == "go1"
        assert node.kd_safe == pytest.approx(1.5)  # 10 Nm s/rad × 13.1 kg / 86.8 kg (two digits: 0.15)
        z_stand = float(node.plant.standing_configuration()[2])
        for _ in range(250):  # held standing for 1 s of simulation time
            node._sample()
        assert abs(node.plant.data.qpos[2] - z_stand) < 0.01 and 0.3 < z_stand < 0.35
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)

    for args, words in ((["-p", "robot:=hyq", "-p", "scenario:=go1_gap"], "is for robot go1, not hyq"),
                        (["-p", "robot:=nope"], "nope")):
        proc = start_node("mujoco_bridge", *args)
        out, _ = proc.communicate(timeout=60)
        lines = [line for line in out.strip().splitlines() if "error" in line.lower()]
        assert proc.returncode == 1 and len(lines) == 1 and words in lines[0], out
        assert "Traceback" not in out
    del subprocess
