"""The simulated robot: MuJoCo physics at 1 kHz, the joint PD loop, the scenario's effects.

Where each effect acts (DESIGN §5):
- the 1 kHz joint loop computes u = u_ff + K_p (q_target − q_meas) + K_d (q̇_target − q̇_meas),
  clipped to the torque limits (TorqueCommand.msg, ciml_learning.conversions.commanded_torque);
- the actuator delivers τ = g · lag(u) + o (actuator_lag, torque_gain, torque_offset):
  between command and torque sensor, so they show in Γ = τ − u;
- the torque sensor reads τ (+ noise);
- joint friction acts on the joint after the sensor (MuJoCo frictionloss for Coulomb,
  damping for viscous — both integrated implicitly, so no chatter at zero velocity), as do
  the out-of-catalogue torques (Stribeck friction, joint spring, torque ripple): they show
  in Φ̃, not in Γ;
- payload and link mass scaling change the MuJoCo model's inertias only;
- encoder offset and IMU tilt change only what is measured (the PD loop sees the
  offset encoder too, as on the real robot); sensor noise likewise.

Measurement convention: measure() at time t reports the joint loop's u(t) under the
command in force before t (with the measured q(t), q̇(t) it reports) and the τ(t) the
actuator delivers for it — the pairing ciml_learning.bagio.load_sensor_log rebuilds.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np
import pinocchio as pin

from ciml_learning.conversions import commanded_torque
from ciml_learning.robot import RobotDescription

from .mjcf import FOOT_RADIUS, build_mjcf, mj_to_pin_acceleration, mj_to_pin_force, mj_to_pin_state, pin_to_mj_state
from .scenario import Scenario

DT = 0.001
CONTACT_THRESHOLD = 1.0  # [N] normal force above which a foot counts as in contact


@dataclass
class Measurement:
    """What the robot's sensors report at one instant (joint order of the robot)."""

    time: float
    q: np.ndarray
    qd: np.ndarray
    tau_measured: np.ndarray
    u_commanded: np.ndarray
    base_position: np.ndarray
    base_orientation: np.ndarray  # quaternion x, y, z, w
    base_linear_velocity: np.ndarray  # base frame
    base_angular_velocity: np.ndarray  # base frame
    contacts: np.ndarray


@dataclass
class GroundTruth:
    """Simulation-only truth at the current instant, Pinocchio conventions."""

    q: np.ndarray
    v: np.ndarray
    vdot: np.ndarray
    contact_forces: np.ndarray  # n_feet × 3, world frame [N]
    effect_forces: dict[str, np.ndarray] = field(default_factory=dict)  # generalized force on the robot [N, Nm]


def true_pinocchio_model(robot: RobotDescription, scenario: Scenario) -> pin.Model:
    """A copy of the nominal model with the scenario's inertial effects (payload, link mass)."""
    model = robot.model.copy()
    for e in scenario.of_type("payload"):
        # point mass in the trunk frame, expressed in the root joint frame
        trunk = model.frames[model.getFrameId("trunk")] if model.existFrame("trunk") else None
        placement = trunk.placement if trunk is not None else pin.SE3.Identity()
        point = pin.Inertia(e.params["mass"], np.asarray(e.params["com"]), np.zeros((3, 3)))
        model.inertias[1] = model.inertias[1] + placement.act(point)
    for e in scenario.of_type("link_mass_scale"):
        frame = model.frames[model.getFrameId(e.link)]
        delta = frame.placement.act(frame.inertia)
        s = e.params["value"] - 1.0
        scaled = pin.Inertia(s * delta.mass, delta.lever, s * delta.inertia)
        model.inertias[frame.parentJoint] = model.inertias[frame.parentJoint] + scaled
    return model


class Plant:
    """MuJoCo robot with a 1 kHz joint loop and the scenario's effects."""

    def __init__(self, robot: RobotDescription, scenario: Scenario, seed: int = 0) -> None:
        self.robot = robot
        self.scenario = scenario
        nj = robot.n_joints
        self.true_model = true_pinocchio_model(robot, scenario)
        self._true_data = self.true_model.createData()
        self._nom_data = robot.model.createData()
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(robot, self.true_model))
        self.data = mujoco.MjData(self.model)
        self.model.opt.timestep = DT
        self.dof = 6 + np.arange(nj)
        self.lag = np.zeros(nj)
        self.gain = np.ones(nj)
        self.offset = np.zeros(nj)
        self.encoder = np.zeros(nj)
        self.stribeck: list = []
        self.springs: list = []
        self.ripples: list = []
        for e in scenario.effects:
            j = np.asarray(e.joints, dtype=int)
            if e.type == "joint_coulomb_friction":
                self.model.dof_frictionloss[6 + j] += e.params["value"]
            elif e.type == "joint_viscous_friction":
                self.model.dof_damping[6 + j] += e.params["value"]
            elif e.type == "actuator_lag":
                self.lag[j] = e.params["time_constant"]
            elif e.type == "torque_gain":
                self.gain[j] *= e.params["value"]
            elif e.type == "torque_offset":
                self.offset[j] += e.params["value"]
            elif e.type == "encoder_offset":
                self.encoder[j] += e.params["value"]
            elif e.type == "joint_stribeck_friction":
                self.stribeck.append((j, e.params))
            elif e.type == "joint_spring":
                self.springs.append((j, e.params))
            elif e.type == "torque_ripple":
                self.ripples.append((j, e.params))
        tilt = scenario.of_type("base_imu_tilt")
        self.imu_tilt = pin.rpy.rpyToMatrix(sum(e.params["roll"] for e in tilt), sum(e.params["pitch"] for e in tilt), 0.0)
        self.noise = {k: scenario.sensor_noise.get(k, 0.0) for k in
                      ("q", "qd", "tau", "base_orientation", "base_position", "base_velocity")}
        self.rng = np.random.default_rng(seed)
        self.foot_geoms = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, f) for f in robot.foot_frames]
        self.limits = robot.torque_limits
        self.reset()

    # --- state -----------------------------------------------------------------------
    @property
    def time(self) -> float:
        return float(self.data.time)

    def standing_configuration(self) -> np.ndarray:
        """Pinocchio q of the standing pose, feet on the floor."""
        q = pin.neutral(self.robot.model)
        q[7:] = self.robot.standing_joints
        data = self.robot.model.createData()
        pin.framesForwardKinematics(self.robot.model, data, q)
        lowest = min(data.oMf[f].translation[2] for f in self.robot.foot_frame_ids)
        q[2] = -lowest + FOOT_RADIUS
        return q

    def reset(self, q0: np.ndarray | None = None) -> None:
        mujoco.mj_resetData(self.model, self.data)
        q = self.standing_configuration() if q0 is None else np.asarray(q0, float)
        qpos, qvel = pin_to_mj_state(q, np.zeros(self.robot.nv))
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)
        nj = self.robot.n_joints
        self.cmd = (np.zeros(nj), q[7:].copy(), np.zeros(nj), np.zeros(nj), np.zeros(nj))
        self.damping_mode = False
        self.kd_safe = np.zeros(nj)
        self.lag_state = np.zeros(nj)
        self.u = np.zeros(nj)
        self.tau = np.zeros(nj)
        self._meas_cache: tuple[float, np.ndarray, np.ndarray] | None = None

    def set_command(self, u_ff: np.ndarray, q_target: np.ndarray, qd_target: np.ndarray, kp: np.ndarray,
                    kd: np.ndarray, damping_mode: bool = False) -> None:
        """Hold a TorqueCommand until the next one; in damping mode u = −kd·q̇ only."""
        self.cmd = tuple(np.asarray(x, dtype=float).copy() for x in (u_ff, q_target, qd_target, kp, kd))
        self.damping_mode = damping_mode

    # --- the 1 kHz joint loop ------------------------------------------------------------
    def _encoders(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint readings at the current instant (one draw per instant, shared with measure())."""
        if self._meas_cache is not None and self._meas_cache[0] == self.data.time:
            return self._meas_cache[1], self._meas_cache[2]
        nj = self.robot.n_joints
        q = self.data.qpos[7:] + self.encoder + self.noise["q"] * self.rng.standard_normal(nj)
        qd = self.data.qvel[6:] + self.noise["qd"] * self.rng.standard_normal(nj)
        self._meas_cache = (self.data.time, q, qd)
        return q, qd

    def _joint_loop(self, q_meas: np.ndarray, qd_meas: np.ndarray) -> np.ndarray:
        u_ff, q_t, qd_t, kp, kd = self.cmd
        if self.damping_mode:
            return np.clip(-kd * qd_meas, -self.limits, self.limits)
        return commanded_torque(u_ff, np.zeros_like(u_ff), q_t, qd_t, kp, kd, q_meas, qd_meas, self.limits)

    def _actuator(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(lag state after this step, delivered torque τ = g·lag(u) + o); backward Euler lag."""
        alpha = DT / (self.lag + DT)
        lag_state = self.lag_state + alpha * (u - self.lag_state)
        return lag_state, self.gain * lag_state + self.offset

    def _joint_side_torques(self) -> np.ndarray:
        """Out-of-catalogue torques acting on the joints after the sensor (explicit)."""
        tau = np.zeros(self.robot.n_joints)
        q, qd = self.data.qpos[7:], self.data.qvel[6:]
        for j, p in self.stribeck:
            level = p["coulomb"] + (p["breakaway"] - p["coulomb"]) * np.exp(-(qd[j] / p["velocity"]) ** 2)
            tau[j] -= level * np.tanh(qd[j] / 0.01)
        for j, p in self.springs:
            tau[j] -= p["stiffness"] * (q[j] - p["rest"])
        for j, p in self.ripples:
            tau[j] += p["amplitude"] * np.sin(2 * np.pi * q[j] / p["period"])
        return tau

    def step(self, n: int = 1) -> None:
        """Advance n physics steps of 1 ms, running the joint loop at every step."""
        d = self.data
        for _ in range(n):
            q_meas, qd_meas = self._encoders()
            self.u = self._joint_loop(q_meas, qd_meas)
            self.lag_state, self.tau = self._actuator(self.u)
            d.qfrc_applied[6:] = self.tau + self._joint_side_torques()
            mujoco.mj_step(self.model, d)

    # --- sensors ----------------------------------------------------------------------
    def _contact_forces(self) -> np.ndarray:
        forces = np.zeros((self.robot.n_feet, 3))
        f6 = np.zeros(6)
        for i in range(self.data.ncon):
            c = self.data.contact[i]
            for k, g in enumerate(self.foot_geoms):
                if g in (c.geom1, c.geom2):
                    mujoco.mj_contactForce(self.model, self.data, i, f6)
                    world = c.frame.reshape(3, 3).T @ f6[:3]
                    forces[k] += world if g == c.geom2 else -world
        return forces

    def measure(self) -> Measurement:
        nj = self.robot.n_joints
        q_meas, qd_meas = self._encoders()
        u = self._joint_loop(q_meas, qd_meas)
        _, tau = self._actuator(u)
        q_true, v_true = mj_to_pin_state(self.data.qpos, self.data.qvel)
        R = pin.Quaternion(q_true[3:7]).matrix() @ self.imu_tilt
        if self.noise["base_orientation"] > 0:
            R = R @ pin.exp3(self.noise["base_orientation"] * self.rng.standard_normal(3))
        nb = self.noise["base_velocity"]
        return Measurement(
            time=self.time,
            q=q_meas.copy(),
            qd=qd_meas.copy(),
            tau_measured=tau + self.noise["tau"] * self.rng.standard_normal(nj),
            u_commanded=u,
            base_position=q_true[:3] + self.noise["base_position"] * self.rng.standard_normal(3),
            base_orientation=pin.Quaternion(R).coeffs().copy(),
            base_linear_velocity=v_true[:3] + nb * self.rng.standard_normal(3),
            base_angular_velocity=v_true[3:6] + nb * self.rng.standard_normal(3),
            contacts=np.linalg.norm(self._contact_forces(), axis=1) > CONTACT_THRESHOLD,
        )

    def ground_truth(self) -> GroundTruth:
        """True state, acceleration, contact forces and each effect's generalized force."""
        m, d = self.model, self.data
        mujoco.mj_forward(m, d)
        q, v = mj_to_pin_state(d.qpos, d.qvel)
        vdot = mj_to_pin_acceleration(q, v, d.qacc)
        nv = self.robot.nv
        effects: dict[str, np.ndarray] = {}
        friction = np.zeros(nv)
        for row in range(d.nefc):
            if d.efc_type[row] == mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF:
                friction[d.efc_id[row]] += d.efc_force[row]
        u = self.u
        lag_out = self.lag_state
        for e in self.scenario.effects:
            f = np.zeros(nv)
            j = 6 + np.asarray(e.joints, dtype=int)
            if e.type == "joint_coulomb_friction":
                f[j] = friction[j]
            elif e.type == "joint_viscous_friction":
                f[j] = -e.params["value"] * d.qvel[j]
            elif e.type == "actuator_lag":
                f[j] = (lag_out - u)[j - 6]
            elif e.type == "torque_gain":
                f[j] = ((self.gain - 1.0) * lag_out)[j - 6]
            elif e.type == "torque_offset":
                f[j] = self.offset[j - 6]
            elif e.type in ("payload", "link_mass_scale"):
                continue  # combined below: both change the same inertias
            elif e.type in ("joint_stribeck_friction", "joint_spring", "torque_ripple"):
                continue
            else:
                continue  # measurement-only effects exert no force
            effects[e.label] = f
        if self.scenario.of_type("payload", "link_mass_scale"):
            # generalized force the nominal model misses: −[(M_true − M) v̇ + (h_true − h)]
            f = -(pin.rnea(self.true_model, self._true_data, q, v, vdot) - pin.rnea(self.robot.model, self._nom_data, q, v, vdot))
            effects["inertial"] = f
        extra = self._joint_side_torques()
        if np.any(extra):
            f = np.zeros(nv)
            f[6:] = extra
            effects["unmodelled_joint_torque"] = f
        return GroundTruth(q=q, v=v, vdot=vdot, contact_forces=self._contact_forces(), effect_forces=effects)
