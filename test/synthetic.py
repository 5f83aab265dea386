"""Small synthetic robot logs written as real rosbag2 MCAP bags (no simulator needed)."""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.logs import bagio


def write_synthetic_bag(robot, path, seconds: float = 3.0, fs: float = 250.0, seed: int = 0,
                        corrupt=None) -> dict:
    """Smooth joint/base motion, trot-like contacts, noisy torques and commands.

    corrupt(k, fields) may modify the per-sample dict before it is written (bad-input tests).
    """
    rng = np.random.default_rng(seed)
    n = int(seconds * fs)
    t = np.arange(n) / fs
    stance = np.array([0.0, 0.7, -1.4, 0.0, -0.7, 1.4] * 2)
    phase = rng.uniform(0, 2 * np.pi, 12)
    qj = stance + 0.15 * np.sin(2 * np.pi * 1.1 * t[:, None] + phase)
    qdj = 0.15 * 2 * np.pi * 1.1 * np.cos(2 * np.pi * 1.1 * t[:, None] + phase)
    gait = (t * 1.5) % 1.0 < 0.5
    contacts = np.stack([gait, ~gait, ~gait, gait], axis=1)
    with bagio.BagWriter(path) as w:
        for k in range(n):
            ns = int(round(t[k] * 1e9))
            rpy = 0.05 * np.sin(2 * np.pi * 0.5 * t[k] + np.array([0.0, 1.0, 2.0]))
            quat = pin.Quaternion(pin.rpy.rpyToMatrix(*rpy)).coeffs()
            f = {
                "q": qj[k], "qd": qdj[k], "tau": 30 * np.sin(qj[k]) + rng.normal(scale=0.5, size=12),
                "pos": np.array([0.1 * t[k], 0.0, 0.6]), "quat": quat,
                "lin": np.array([0.1, 0.0, 0.0]), "ang": 0.1 * np.cos(2 * np.pi * 0.5 * t[k] + np.arange(3)),
                "contacts": contacts[k], "joint_names": list(robot.joint_names),
            }
            if corrupt is not None:
                corrupt(k, f)
            js = cv.joint_state_msg(robot, ns, f["q"], f["qd"], f["tau"])
            js.name = f["joint_names"]
            w.write(topics.JOINT_STATES, ns, js)
            w.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, f["pos"], f["quat"], f["lin"], f["ang"]))
            w.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(robot, ns, f["contacts"]))
            cmd = cv.TorqueCommandArrays(0, 30 * np.sin(qj[k]), np.zeros(12), qj[k], qdj[k],
                                         np.full(12, 200.0), np.full(12, 5.0))
            w.write(topics.TORQUE_COMMAND, ns, cv.torque_command_msg(robot, ns, cmd))
    return {"samples": n}
