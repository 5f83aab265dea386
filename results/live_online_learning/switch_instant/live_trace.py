"""The go1 live graph (go1_gap, trot_35, lockstep, seed 42, no learning) serving one fixed model,
traced from outside in windows W [s after the first torque command]: every command, joint state,
base state, /reference and /model_error/predicted received there, and the feedback effort of
every command (GraphProbe).

    python live_trace.py OUT.npz DURATION MODEL [launch_key=value ...]   → analyse.py OUT.npz
"""
import os
import sys
import tempfile
import threading
import time

import numpy as np
import rclpy
from ciml_msgs.msg import ModelError, RobotReference, TorqueCommand
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.profile import load_profile
from ciml_learning.ros.graph_probe import GraphProbe
from ciml_learning.ros.ros_common import COMMAND_QOS
from ciml_sim.live_bench import start_graph

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", "78")
out, duration, model = sys.argv[1], float(sys.argv[2]), sys.argv[3]
extra = dict(a.split("=", 1) for a in sys.argv[4:])
robot = load_profile("go1").robot()
W = [(100, 130), (290, 340), (400, 430), (560, 590)]
t_first: list[float] = []
rec: dict[str, list] = {k: [] for k in ("cmd", "js", "base", "pred", "ref")}


def stamp(m) -> float:
    return m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec


def kept(t: float) -> bool:
    return bool(t_first) and any(a <= t - t_first[0] <= b for a, b in W)


def on_command(m) -> None:
    if kept(t := stamp(m)):
        c = cv.torque_command_arrays(robot, m)
        rec["cmd"].append(np.concatenate([[t, time.monotonic(), c.mode], c.feedforward, c.feedback_linearization,
                                          c.position_target, c.velocity_target, c.stiffness, c.damping]))


def on_joints(m) -> None:
    if kept(t := stamp(m)):
        rec["js"].append(np.concatenate([[t, time.monotonic()], *cv.joint_state_arrays(robot, m)]))


def on_base(m) -> None:
    if kept(t := stamp(m)):
        p, v, w = m.pose.pose, m.twist.twist.linear, m.twist.twist.angular
        rec["base"].append([t, p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y,
                            p.orientation.z, p.orientation.w, v.x, v.y, v.z, w.x, w.y, w.z])


def on_prediction(m) -> None:
    if kept(t := stamp(m)):
        rec["pred"].append(np.concatenate([[t], m.rbd_error, m.actuation_error, m.rbd_variance,
                                           m.actuation_variance]))


def on_reference(m) -> None:
    if kept(t := stamp(m)):
        rec["ref"].append(np.concatenate([[t, m.phase], m.position, m.velocity, m.acceleration, m.in_contact]))


ctx = rclpy.Context()
rclpy.init(args=[], context=ctx)
node = rclpy.create_node("switch_instant_trace", context=ctx)
node.create_subscription(TorqueCommand, topics.TORQUE_COMMAND, on_command, COMMAND_QOS)
node.create_subscription(JointState, topics.JOINT_STATES, on_joints, qos_profile_sensor_data)
node.create_subscription(Odometry, topics.BASE_STATE, on_base, qos_profile_sensor_data)
node.create_subscription(ModelError, topics.MODEL_ERROR_PREDICTED, on_prediction, COMMAND_QOS)
node.create_subscription(RobotReference, topics.REFERENCE, on_reference, COMMAND_QOS)
executor = SingleThreadedExecutor(context=ctx)
executor.add_node(node)
threading.Thread(target=executor.spin, daemon=True).start()
log_dir = tempfile.mkdtemp(prefix="switch_instant_")
args = {"robot": "go1", "scenario": "go1_gap", "seed": "42", "online_learning": "false", "model_dir": f"{log_dir}/m",
        "model": model, **extra}
probe = GraphProbe(effort_robot=robot, nice=10)
launcher, log = start_graph(args, log_dir)
try:
    assert probe.wait_for(lambda: probe.first_torque_stamp is not None, 120)
    t_first.append(probe.first_torque_stamp * 1e-9)
    while probe.sim_time() - t_first[0] < duration:
        time.sleep(0.5)
finally:
    rc = launcher.stop()
    log.close()
    with probe.lock:
        efforts = np.array(probe.efforts)
    probe.close()
    executor.shutdown()
    np.savez(out, eff=efforts, t0=t_first[0], **{k: np.array(v) for k, v in rec.items()})
    print("rc", rc, "log", log_dir)
