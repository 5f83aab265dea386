"""Scenario bags for the diagnosis tests, recorded from the simulated plant (ciml_sim.plant).

A test-side generator (not part of the product): the plant with a scenario's effects,
driven by a posture controller (joint PD around inverse-kinematics targets plus static
gravity compensation, ciml_control.standing) through a motion that excites the base
and, optionally, lifts each leg in turn (so the swing-foot entries of Φ̃' are observed).
Bags hold the four live topics, and the /sim/ ground truth when asked.
"""
from __future__ import annotations

import os

import numpy as np
import pinocchio as pin

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.robot import RobotDescription
from ciml_learning.logs import bagio

FS = 250.0
STEPS_PER_TICK = 4
STAMP_OFFSET_NS = 1_000_000_000  # stamps start at 1 s (commands are stamped 1 ns before their sample)


def _leg_ik(robot: RobotDescription, data, q: np.ndarray, feet_world: np.ndarray, iters: int = 4) -> np.ndarray:
    """Joint angles (in q, base fixed) that put each foot at feet_world (n_feet × 3); Newton steps."""
    q = q.copy()
    model = robot.model
    for _ in range(iters):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        for i, f in enumerate(robot.foot_frame_ids):
            cols = 6 + np.asarray(robot.leg_joints[i])
            J = pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3, cols]
            err = feet_world[i] - data.oMf[f].translation
            q[1 + cols] += np.linalg.lstsq(J, err, rcond=1e-3)[0]
    return q


class PostureMotion:
    """Base sway with the feet fixed, then (legs=True) each leg lifted in turn.

    sample(t) → (base position, base rotation, foot targets (n_feet × 3), stance flags).
    """

    def __init__(self, robot: RobotDescription, q0: np.ndarray, legs: bool, seed: int, scale: float = 1.0):
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, q0)
        self.feet0 = np.array([data.oMf[f].translation.copy() for f in robot.foot_frame_ids])
        self.base0 = q0[:3].copy()
        rng = np.random.default_rng(seed)
        self.freq = rng.uniform(0.25, 0.6, 6)
        self.phase = rng.uniform(0, 2 * np.pi, 6)
        self.amp = scale * np.array([0.035, 0.025, 0.03, 0.07, 0.07, 0.08])
        self.legs = legs
        self.leg_period = 2.4  # s per lifted leg
        self.sway_time = 2.0
        self.robot = robot

    def sample(self, t: float):
        n_feet = len(self.feet0)
        off = self.amp * np.sin(2 * np.pi * self.freq * t + self.phase)
        ramp = min(1.0, t / 0.5)
        off = off * ramp
        feet = self.feet0.copy()
        stance = np.ones(n_feet, dtype=bool)
        if self.legs and t >= self.sway_time:
            tl = t - self.sway_time
            k = int(tl // self.leg_period) % n_feet
            s = (tl % self.leg_period) / self.leg_period  # 0..1 within this leg's turn
            centroid = np.mean(np.delete(self.feet0, k, axis=0), axis=0)
            # shift the base towards the support triangle, hold, lift and circle the foot, put down
            w = np.clip(np.sin(np.pi * s) * 1.6, 0.0, 1.0)
            off = off * 0.3
            off[:2] += w * 0.75 * (centroid[:2] - np.mean(self.feet0[:, :2], axis=0))
            if 0.25 < s < 0.75:
                sl = (s - 0.25) / 0.5
                lift = np.sin(np.pi * sl)
                feet[k] = self.feet0[k] + np.array([0.05 * np.sin(2 * np.pi * sl), 0.03 * np.sin(4 * np.pi * sl),
                                                    0.10 * lift])
                stance[k] = not (0.02 < sl < 0.98)
        pos = self.base0 + off[:3]
        R = pin.rpy.rpyToMatrix(*off[3:])
        return pos, R, feet, stance


def record_plant_bag(robot: RobotDescription, scenario: dict, path: str | os.PathLike, seconds: float = 4.0,
                     seed: int = 0, legs: bool = True, ground_truth: bool = True, motion_seed: int | None = None,
                     scale: float = 1.0, kp: float = 800.0, kd: float = 12.0, timing: str = "foh") -> dict:
    """Simulate the scenario (a dict, as a YAML file would hold) and write a bag.

    timing: how the 250 Hz commands reach the 1 kHz joint loop. "foh": targets and feedforward
    interpolated every 1 ms, so the torque sampled at a tick is the torque that acts around it;
    "recorder": held from the tick on, as ciml_sim.recorder did before the joint loop's target
    followed the velocity target (the sample at a tick reports the torque under the previous
    command, which then jumps); "delayed": held from half a tick later (a compute delay: no jump
    at the sample instant). Both hold the position target (TorqueCommand.msg now moves it): the
    command is set again, stamped now, at every 1 ms step and before each sample, and is stamped
    in the bag 1 ns before the next sample, so the bag's u there is the held target's torque.

    Returns {"samples", "fell", "ground_truth_topics"}.
    """
    from ciml_control.standing import gravity_compensation
    from ciml_learning.core.dynamics import RigidBodyDynamics
    from ciml_sim.plant import Plant
    from ciml_sim.scenario import parse_scenario

    scen = parse_scenario(scenario, robot)
    plant = Plant(robot, scen, seed=seed)
    plant.reset()
    q0 = plant.standing_configuration()
    motion = PostureMotion(robot, q0, legs, seed if motion_seed is None else motion_seed, scale)
    dyn = RigidBodyDynamics(robot)
    ik_data = robot.model.createData()
    nj = robot.n_joints
    n_ticks = int(round(seconds * FS))
    q_prev = q0.copy()
    fell = False
    gt_topics: set[str] = set()
    kp_v, kd_v = np.full(nj, kp), np.full(nj, kd)
    u_prev = None
    held = None  # recorder/delayed: the command in force
    with bagio.BagWriter(path) as w:
        for k in range(n_ticks):
            t_k = plant.time
            # the measurement at t_k pairs with the command acting from t_k on (set below first)
            pos, R, feet, stance = motion.sample(t_k)
            q_des = q_prev.copy()
            q_des[:3] = pos
            q_des[3:7] = pin.Quaternion(R).coeffs()
            q_des = _leg_ik(robot, ik_data, q_des, feet)
            qd_des = (q_des[7:] - q_prev[7:]) * FS if k > 0 else np.zeros(nj)
            q_prev = q_des
            u_ff = np.clip(gravity_compensation(dyn, q_des, stance), -robot.torque_limits, robot.torque_limits)
            du = np.zeros(nj) if u_prev is None else (u_ff - u_prev) * FS
            u_prev = u_ff
            cmd = cv.TorqueCommandArrays(0, u_ff, np.zeros(nj), q_des[7:], qd_des, kp_v, kd_v)
            for s in range(STEPS_PER_TICK):
                if timing == "foh":
                    # first-order hold at the 1 kHz joint loop: targets and feedforward move continuously,
                    # so the torque sampled at t_k is the torque acting right after t_k (no command jump)
                    dt = s / (FS * STEPS_PER_TICK)
                    plant.set_command(u_ff + du * dt, q_des[7:] + qd_des * dt, qd_des, kp_v, kd_v)
                elif held is not None:
                    plant.set_command(*held)  # stamped now: zero elapsed time, the target held
                if s == 0:
                    m = plant.measure()
                    ns = int(round(m.time * 1e9)) + STAMP_OFFSET_NS
                    w.write(topics.JOINT_STATES, ns, cv.joint_state_msg(robot, ns, m.q, m.qd, m.tau_measured))
                    w.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, m.base_position, m.base_orientation,
                                                                 m.base_linear_velocity, m.base_angular_velocity))
                    w.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(robot, ns, m.contacts))
                    # foh: stamped just before t_k, the command in force at t_k (bagio pairs strictly-before);
                    # otherwise stamped t_k: computed from this sample, in force for the next one
                    # recorder/delayed: in force for the next sample, with its target held (see above)
                    stamp = ns - 1 if timing == "foh" else ns + round(1e9 / FS) - 1
                    w.write(topics.TORQUE_COMMAND, stamp, cv.torque_command_msg(robot, stamp, cmd))
                    if ground_truth:
                        gt = plant.ground_truth()
                        _write_truth(w, robot, ns, gt)
                        gt_topics.update(topics.SIM_EFFECT_PREFIX + label for label in gt.effect_forces)
                    if m.base_position[2] < 0.3 or not np.all(np.isfinite(m.q)):
                        fell = True
                        break
                if (timing == "recorder" and s == 0) or (timing == "delayed" and s == STEPS_PER_TICK // 2):
                    held = (u_ff, q_des[7:], qd_des, kp_v, kd_v)
                    plant.set_command(*held)
                plant.step(1)
            if fell:
                break
    return {"samples": k + 1, "fell": fell, "ground_truth_topics": sorted(gt_topics)}


def _write_truth(writer, robot: RobotDescription, ns: int, truth) -> None:
    from ciml_msgs.msg import ContactForces, GeneralizedForce

    header = cv.header_msg(ns)
    dof = list(robot.dof_names)
    writer.write(topics.SIM_ACCELERATION, ns, GeneralizedForce(header=header, label="acceleration", names=dof,
                                                                values=np.asarray(truth.vdot, float).tolist()))
    f = np.asarray(truth.contact_forces, float)
    writer.write(topics.SIM_CONTACT_FORCES, ns, ContactForces(header=header, foot_names=list(robot.foot_frames),
                                                               force_x=f[:, 0].tolist(), force_y=f[:, 1].tolist(),
                                                               force_z=f[:, 2].tolist()))
    for label, force in truth.effect_forces.items():
        writer.write(topics.SIM_EFFECT_PREFIX + label, ns,
                     GeneralizedForce(header=header, label=label, names=dof, values=np.asarray(force, float).tolist()))


def read_ground_truth(robot: RobotDescription, path: str | os.PathLike) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Test-side reader of the /sim/ topics: {topic: (t [s], values (N × k))}."""
    names = bagio.list_topics(path)
    wanted = [t for t in names if topics.is_ground_truth(t)]
    msgs = bagio.read_messages(path, wanted)
    out = {}
    for topic, rows in msgs.items():
        t = np.array([s for s, _ in rows]) * 1e-9
        if topic == topics.SIM_CONTACT_FORCES:
            vals = np.array([np.stack([m.force_x, m.force_y, m.force_z], axis=1) for _, m in rows])
        else:
            vals = np.array([np.asarray(m.values, float) for _, m in rows])
        out[topic] = (t, vals)
    return out


def copy_topics(src: str | os.PathLike, dst: str | os.PathLike, keep) -> None:
    """Rewrite a bag with only the topics for which keep(topic) is true (raw CDR copied as is)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    writer = Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    conns = {}
    try:
        for topic, log_ns, raw, msgtype in bagio.iter_bag_messages(src):
            if not keep(topic):
                continue
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=bagio.typestore())
            writer.write(conns[topic], log_ns, raw)
    finally:
        writer.close()


def strip_to_live_topics(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Rewrite a bag with only the four live sensor topics (no /sim/, no /clock)."""
    copy_topics(src, dst, lambda t: t in topics.SENSOR_TOPICS)
