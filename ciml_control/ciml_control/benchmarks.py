"""Benchmarks of ciml_control (`ciml bench`, registered in setup.py under the `ciml.benchmarks` entry points).

Each function runs with its defaults as the benchmark's settings and returns one JSON-able dict.
Compare numbers from one run only: the machines are shared and noisy.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np
import pinocchio as pin
import rclpy
from ciml_msgs.msg import ContactState, RobotReference, TorqueCommand
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from sensor_msgs.msg import JointState

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.dynamics import selection_matrix
from ciml_learning.core.extraction import combined_error
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_learning.ros.ros_common import COMMAND_QOS, SENSOR_PUB_QOS

from .controller import IdController
from .conversions import reference_msg
from .nodes.id_controller import MODE_TORQUE
from .references import make_reference, standing_configuration


def id_controller_step() -> dict:
    """The controller's compute() per step, trot_35 (compute_benchmark)."""
    return compute_benchmark(motion="trot_35", n_steps=2000)


def compute_benchmark(motion: str = "trot_35", n_steps: int = 2000, seed: int = 0,
                      model_dir: str | None = None) -> dict:
    """p50/p99 of one control step as the id_controller node runs it: the model error ε at
    the reference (eq. 17: contact-invariant basis at qᵈ and a Φ̃', Γ prediction — from
    `model_dir` via ciml_learning.learning.model_epsilon.load_epsilon_function if given, else a fixed
    prediction) plus IdController.compute() (QP included), along a reference with a
    perturbed measured state. Reference samples are precomputed (the node receives them
    on /reference). Target p99 ≤ 1 ms (budget at 250 Hz: 4 ms)."""
    robot = load_robot()
    q_stand = standing_configuration(robot, 0.002)
    ref = make_reference(robot, motion, q_stand)
    rng = np.random.default_rng(seed)
    ts = 1.0 + np.arange(n_steps) / 250.0
    points = [ref.sample(t) for t in ts]
    ctrl = IdController(robot)
    S = selection_matrix(robot)
    phi = rng.normal(0.0, 5.0, len(robot.rbd_error_names))
    gamma = rng.normal(0.0, 2.0, robot.n_joints)
    if model_dir is not None:
        epsilon_fn = load_epsilon_function(robot, model_dir)
    else:
        def epsilon_fn(p):  # the contact Jacobians at qᵈ from the controller's pass at the reference
            basis = contact_invariant_basis(ctrl.desired_terms(p)[2], robot.leg_joints)
            return combined_error(basis, phi, gamma, S)
    for p in points[:50]:  # warm-up
        ctrl.compute(p.q, p.v, p.contacts, p, epsilon_fn(p))
    times = []  # (start, ε done, compute() done) per step
    for p in points:
        q = pin.integrate(robot.model, p.q, 0.005 * rng.standard_normal(robot.nv))
        v = p.v + 0.05 * rng.standard_normal(robot.nv)
        t0 = time.perf_counter()
        eps = epsilon_fn(p)
        t1 = time.perf_counter()
        ctrl.compute(q, v, p.contacts, p, eps)
        times.append((t0, t1, time.perf_counter()))
    t = np.array(times) * 1e6
    step, eps_part, compute_part = t[:, 2] - t[:, 0], t[:, 1] - t[:, 0], t[:, 2] - t[:, 1]

    def pct(x: np.ndarray, k: float) -> float:
        return round(float(np.percentile(x, k)), 1)

    return {"motion": motion, "steps": n_steps, "model": model_dir or "fixed prediction",
            "p50_us": pct(step, 50), "p99_us": pct(step, 99), "max_us": round(float(step.max()), 1),
            # the step in two: ε at the reference (its Pinocchio pass at qᵈ, the basis, eq. 17) and
            # compute() (one compiled call: the measured state's pass, the null-space QP, the feedback)
            "epsilon_p50_us": pct(eps_part, 50), "compute_p50_us": pct(compute_part, 50),
            "qp_failures": ctrl.qp_failures, "target_p99_us": 1000.0}


def dds_latency_benchmark(duration_s: float = 5.0, rate: float = 250.0) -> dict:
    """End-to-end latency state → command over DDS (loopback): this process publishes a
    standing robot's /joint_states (+ base, contacts, reference) at `rate` Hz to an
    `id_controller` process and times each /torque_command stamped with that sample."""
    env = dict(os.environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
    os.environ.update({k: env[k] for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_DOMAIN_ID")})
    proc = subprocess.Popen([os.path.join(sys.prefix, "bin", "id_controller")], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    robot = load_robot()
    q_stand = standing_configuration(robot, 0.002)
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("latency_probe", context=context)
    sent: dict[int, float] = {}
    latencies: list[float] = []

    def on_command(msg) -> None:
        t = time.perf_counter()
        ns = cv.stamp_to_ns(msg.header.stamp)
        if msg.mode == MODE_TORQUE and ns in sent:
            latencies.append(t - sent.pop(ns))

    node.create_subscription(TorqueCommand, topics.TORQUE_COMMAND, on_command, COMMAND_QOS)
    pub_j = node.create_publisher(JointState, topics.JOINT_STATES, SENSOR_PUB_QOS)
    pub_b = node.create_publisher(Odometry, topics.BASE_STATE, SENSOR_PUB_QOS)
    pub_c = node.create_publisher(ContactState, topics.CONTACT_STATE, SENSOR_PUB_QOS)
    pub_r = node.create_publisher(RobotReference, topics.REFERENCE, COMMAND_QOS)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.01)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    n_sent = 0
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and (pub_j.get_subscription_count() == 0
                                               or node.count_publishers(topics.TORQUE_COMMAND) == 0):
            time.sleep(0.1)
        if pub_j.get_subscription_count() == 0:
            return {"error": "id_controller did not come up within 60 s"}
        nj = robot.n_joints
        period = 1.0 / rate
        next_t = time.perf_counter()
        warmup = int(rate)  # the first second is not timed
        for k in range(int((duration_s + 1.0) * rate)):
            ns = time.time_ns()
            pub_r.publish(reference_msg(robot, ns, ref))
            pub_b.publish(cv.odometry_msg(ns, q_stand[:3], q_stand[3:7], np.zeros(3), np.zeros(3)))
            pub_c.publish(cv.contact_state_msg(robot, ns, np.ones(robot.n_feet, bool)))
            msg = cv.joint_state_msg(robot, ns, q_stand[7:], np.zeros(nj), np.zeros(nj))
            if k >= warmup:
                sent[ns] = time.perf_counter()
                n_sent += 1
            pub_j.publish(msg)
            next_t += period
            time.sleep(max(0.0, next_t - time.perf_counter()))
        time.sleep(0.2)
    finally:
        stop.set()
        thread.join(timeout=2)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
    lat = np.array(latencies) * 1e3
    out = {"rate_hz": rate, "sent": n_sent, "received": len(lat)}
    if len(lat):
        out.update({"p50_ms": round(float(np.percentile(lat, 50)), 3),
                    "p99_ms": round(float(np.percentile(lat, 99)), 3),
                    "max_ms": round(float(lat.max()), 3), "budget_ms": round(1e3 / rate, 1)})
    return out
