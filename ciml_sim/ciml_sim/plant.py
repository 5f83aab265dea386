"""The simulated robot: MuJoCo physics at 1 kHz, the joint PD loop, the scenario's effects.

Where each effect acts (docs/ARCHITECTURE.md §5), from command to motion:

    command (u_ff, q_t, q̇_t, K_p, K_d, stamp t_c)  held until the next one
    → joint loop, every 1 ms (time s), on the *measured* q, q̇ (encoder offset and noise
      included, as on the robot), the position target moving along the velocity target
      from the command's stamp (TorqueCommand.msg):
          u = clip(u_ff + K_p (q_t + q̇_t (s − t_c) − q_meas) + K_d (q̇_t − q̇_meas), ±limits)
    → actuator:  τ = g · L(u) + o            actuator_lag (L: first-order lag, backward
                                              Euler), torque_gain (g), torque_offset (o)
    → torque sensor reads τ_m = g_s τ + o_s + a_s sin(2π q/p_s) (+ noise)   so the actuator effects
                                              show in Γ = τ_m − u (eq. 14); torque_sensor_gain (g_s),
                                              torque_sensor_offset (o_s), torque_sensor_ripple (a_s, p_s)
                                              change only the reading: in Γ and, as the nominal model
                                              takes τ_m for the torque, in Φ̃
    → joint: τ + friction + other joint torques
                                              joint_coulomb_friction (MuJoCo frictionloss, an
                                              implicit constraint: true stiction, no chatter),
                                              joint_viscous_friction (MuJoCo damping, implicit),
                                              joint_stribeck_friction (frictionloss whose level
                                              follows the Stribeck curve of the current speed),
                                              joint_spring, torque_ripple (explicit torques):
                                              after the sensor, so they show in Φ̃, not in Γ
    → rigid bodies: payload, link_mass_scale change the MuJoCo model's inertias only
    → sensors: encoder_offset and base_imu_tilt bias what is measured (the joint loop
      sees the offset encoder too); sensor noise likewise.

Timing convention (the one ciml_learning.logs.loginputs.load_log rebuilds): a sample at
time t reports the state at t and the joint loop's u and the actuator's τ at t *under
the command in force before t*, its position target advanced to t (a command computed
from that sample acts after it);
GroundTruth at t is evaluated at the same instant with that same torque: v̇(t),
the contact forces, and each effect's generalized force, which together close eq. (3)
of the nominal model:

    M(q) v̇ + h(q, v) = Sᵀ u + Σ_feet J_footᵀ f_foot + Σ_effects f_effect.

Encoder noise is drawn once per 1 ms joint-loop reading (the loop and the published
sample at that instant see the same reading); the other sensor noise once per sample
(both in blocks of 1000 draws: the same numbers as one draw at a time).

Speed: the joint loop and MuJoCo's step run together in compiled code
(ciml_sim.joint_loop: one call per `step(n)`; the sensors of measure() and the command
coefficients of set_command() are compiled too, and compiled_state() hands all of it to
joint_loop.closed_loop, the headless closed loop without Python between ticks).
measure() runs mj_forward at the sample instant; the first physics step after it
(with the new command) reuses that pass's position and velocity stages (mj_step2
instead of mj_step: bit-identical, as long as nothing but the command changes in
between — a changed state is detected and stepped in full).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np
import pinocchio as pin

from ciml_control.references import standing_configuration
from ciml_learning.core.dynamics import quaternion_xyzw
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription
from ciml_learning.effects.joint_coulomb_friction import FRICTION_SOLIMP, friction_solref

from . import joint_loop
from .effects import SIM_EFFECTS, Truth
from .mjcf import (
    FOOT_RADIUS,
    TIMESTEP,
    build_mjcf,
    mj_to_pin_state,
    pin_to_mj_state,
    quat_xyzw_to_matrix,
)
from .scenario import Effect, Scenario

DT = TIMESTEP
CONTACT_THRESHOLD = 1.0
"""Normal force [N] above which a foot is reported in contact."""
FRICTION_SOLREF = friction_solref(TIMESTEP)
"""The near-ideal Coulomb friction of the registry's MuJoCo form (FRICTION_SOLIMP, its docstring)."""
_NOISE_BLOCK = 1000
_FRICTION_DOF = int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF)  # a plain int: comparing arrays to the enum is slow


class PlantError(CimlError):
    """The plant was given an invalid state or command."""


@dataclass
class Measurement:
    """What the robot's sensors report at one instant (joint order of the robot)."""

    time: float
    q: np.ndarray                      # joint positions [rad] (encoder offset, noise)
    qd: np.ndarray                     # joint velocities [rad/s]
    tau_measured: np.ndarray           # torque sensors [Nm]
    u_commanded: np.ndarray            # the joint loop's total command u [Nm] (not published)
    base_position: np.ndarray          # world [m]
    base_orientation: np.ndarray       # quaternion x, y, z, w (IMU tilt, noise)
    base_linear_velocity: np.ndarray   # base frame [m/s]
    base_angular_velocity: np.ndarray  # base frame [rad/s]
    contacts: np.ndarray               # (n_feet,) bool


@dataclass
class GroundTruth:
    """Simulation-only truth at the current instant, Pinocchio conventions.

    effect_forces[label]: the generalized force (nv; base force and torque in the base
    frame, then joints) [N, Nm] that the effect adds to the right-hand side of eq. (3)
    of the nominal model (see the module docstring). Measurement-only effects
    (encoder_offset, base_imu_tilt) exert none and have no entry.
    """

    q: np.ndarray
    v: np.ndarray
    vdot: np.ndarray
    contact_forces: np.ndarray  # n_feet × 3, world frame, force of the floor on the foot [N]
    u: np.ndarray               # joint loop command [Nm]
    tau: np.ndarray             # torque the actuators deliver (noise-free sensor reading) [Nm]
    effect_forces: dict[str, np.ndarray] = field(default_factory=dict)


# --- inertial effects on the Pinocchio model ----------------------------------------------


def true_pinocchio_model(robot: RobotDescription, effects: list[Effect] | Scenario) -> pin.Model:
    """A copy of the nominal model with the inertial effects (payload, link mass) applied."""
    effects = list(effects.effects) if isinstance(effects, Scenario) else effects
    model = robot.model.copy()
    for e in effects:
        if SIM_EFFECTS[e.type].changes_inertia:
            SIM_EFFECTS[e.type].inertial(robot, model, e)
    return model


# --- the plant ---------------------------------------------------------------------------


class Plant:
    """MuJoCo robot with a 1 kHz joint loop and the scenario's effects."""

    def __init__(self, robot: RobotDescription, scenario: Scenario, seed: int = 0) -> None:
        self.robot = robot
        self.scenario = scenario
        self.seed = int(seed)
        nj = robot.n_joints
        self.true_model = true_pinocchio_model(robot, scenario)
        self.model = mujoco.MjModel.from_xml_string(build_mjcf(robot, self.true_model))
        self.data = mujoco.MjData(self.model)
        mj_joints = tuple(self.model.joint(i).name for i in range(1, self.model.njnt))
        if mj_joints != robot.joint_names:
            raise CimlError(f"MuJoCo joint order {mj_joints} differs from the robot's {robot.joint_names}")
        self.model.dof_solref[6:] = FRICTION_SOLREF
        self.model.dof_solimp[6:] = FRICTION_SOLIMP
        self.limits = robot.torque_limits.copy()
        self._nominal_data = robot.model.createData()

        # per-joint parameters; effects of one type on the same joint add up (scenario.py)
        self.gain = np.ones(nj)
        self.offset = np.zeros(nj)
        self.lag_time_constant = np.zeros(nj)
        self.encoder_offset = np.zeros(nj)
        self.sensor = np.zeros((nj, 4))  # torque sensor per joint: gain, offset, ripple amplitude, period
        self.sensor[:, 0] = 1.0
        self.sensor[:, 3] = 1.0
        self.coulomb = np.zeros(nj)
        self.viscous = np.zeros(nj)
        self.imu_roll = self.imu_pitch = 0.0
        self.friction_levels: list[tuple[Effect, np.ndarray]] = []  # frictionloss levels set between steps
        self.side_effects: list[tuple[Effect, np.ndarray]] = []     # explicit joint torques set between steps
        self._inertial: list[tuple[Effect, pin.Model, pin.Data]] = []
        for e in scenario.effects:  # each effect's simulation module (ciml_sim.effects) sets its part
            sim = SIM_EFFECTS[e.type]
            sim.configure(self, e, np.asarray(e.joints, dtype=int))
            if sim.changes_inertia:
                m = true_pinocchio_model(robot, [e])
                self._inertial.append((e, m, m.createData()))
        self.model.dof_frictionloss[6:] = self.coulomb
        self.model.dof_damping[6:] = self.viscous
        self._gt_effects = [(e, np.asarray(e.joints, dtype=int)) for e in scenario.effects]
        self._gt_friction = any(SIM_EFFECTS[e.type].frictionloss for e in scenario.effects)
        self._alpha = DT / (self.lag_time_constant + DT)  # backward-Euler lag: τ_k = τ_{k−1} + α (u_k − τ_{k−1})
        self._has_lag = bool(np.any(self.lag_time_constant > 0))
        self._has_gain = bool(np.any(self.gain != 1.0) or np.any(self.offset != 0.0))
        identity = np.all(self.sensor[:, 0] == 1.0) and not np.any(self.sensor[:, 1:3])
        self._sensor = np.empty((0, 4)) if identity else self.sensor  # empty: the sensor reads τ
        self._has_side = bool(self.side_effects)
        self._extra = bool(self.friction_levels) or self._has_side  # effects evaluated in Python between steps
        self._no_noise = np.empty((0, nj))
        roll, pitch = self.imu_roll, self.imu_pitch
        tilt = quaternion_xyzw(pin.rpy.rpyToMatrix(roll, pitch, 0.0))  # x y z w
        self._imu_tilt = np.empty(0) if roll == pitch == 0.0 else np.array([tilt[3], tilt[0], tilt[1], tilt[2]])
        self.noise = {k: float(scenario.sensor_noise.get(k, 0.0)) for k in
                      ("q", "qd", "tau", "base_orientation", "base_position", "base_velocity")}
        self._encoder_noisy = self.noise["q"] > 0 or self.noise["qd"] > 0
        self.foot_geoms = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, f) for f in robot.foot_frames]
        self._foot_bodies = np.array([self.model.geom_bodyid[g] for g in self.foot_geoms])
        if len(set(self._foot_bodies.tolist())) != robot.n_feet:
            raise CimlError("two feet on one body: per-foot contact forces cannot be told apart")
        self._base_body = int(self.model.jnt_bodyid[0])
        self._noise_std = np.array([self.noise[k] for k in ("base_orientation", "tau", "base_position",
                                                              "base_velocity")])
        # standard-normal draws per sample: orientation (3), torque (n_j), position (3), twist (6)
        self._meas_noise_len = int(sum(n for n, std in zip((3, nj, 3, 6), self._noise_std) if std > 0))
        # views into MjData (stable buffers)
        d = self.data
        self._qj = d.qpos[7:]
        self._vj = d.qvel[6:]
        self._ctrl = d.ctrl
        self._qfrc_j = d.qfrc_applied[6:]
        self._xmat_base = d.xmat[self._base_body]
        self._no_sample_noise = np.empty(0)
        # the compiled joint loop's records (ciml_sim.joint_loop): the fixed ones; reset() makes the held
        # command and the actuators (with the lag's state)
        fn = joint_loop.mj_function
        self._mujoco = joint_loop.MujocoCalls(fn("mj_step"), fn("mj_step2"), fn("mj_forward"),
                                              fn("mj_rnePostConstraint"), self.model._address, d._address)
        self._sensors = joint_loop.Sensors(self._xmat_base, d.cfrc_ext, self._foot_bodies, self._imu_tilt,
                                           self._noise_std, CONTACT_THRESHOLD, self._sensor)
        self.reset()

    # --- state -----------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return float(self.data.time)

    @property
    def steps(self) -> int:
        """Physics steps since the last reset."""
        return self._k

    def standing_configuration(self) -> np.ndarray:
        """Pinocchio q of the standing pose (robot.standing_joints), feet touching the floor."""
        return standing_configuration(self.robot, FOOT_RADIUS)

    def true_state(self) -> tuple[np.ndarray, np.ndarray]:
        """True (q, v) now, Pinocchio conventions (simulation only)."""
        return mj_to_pin_state(self.data.qpos, self.data.qvel)

    def reset(self, q0: np.ndarray | None = None, v0: np.ndarray | None = None) -> None:
        """Back to time 0 at q0 (default: standing), velocity v0 (default 0), no command
        (zero torque, zero gains), actuators at rest, noise streams restarted."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        q = self.standing_configuration() if q0 is None else np.asarray(q0, dtype=float)
        v = np.zeros(self.robot.nv) if v0 is None else np.asarray(v0, dtype=float)
        if q.shape != (self.robot.nq,) or v.shape != (self.robot.nv,) \
                or not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise PlantError(f"reset: expected finite q ({self.robot.nq}) and v ({self.robot.nv})")
        d.qpos[:], d.qvel[:] = pin_to_mj_state(q, v)
        mujoco.mj_forward(m, d)
        nj = self.robot.n_joints
        seeds = np.random.SeedSequence([self.scenario.seed, self.seed]).spawn(2)
        self._rng_joint = np.random.default_rng(seeds[0])
        self._rng_meas = np.random.default_rng(seeds[1])
        self._noise_start = -_NOISE_BLOCK
        self._meas_noise_i = _NOISE_BLOCK
        self._k = 0
        self._clock = (0.0, 0)  # (time, steps) of the clock's origin: time = origin + steps since · dt
        self._forward_state: bytes | None = None
        self._actuators = joint_loop.Actuators(self.encoder_offset, self.limits, self._has_lag, self._alpha,
                                               np.zeros(nj), self._has_gain, self.gain, self.offset)
        self._command = joint_loop.HeldCommand(np.zeros(nj), np.zeros(nj), np.zeros(nj), np.zeros(nj), False, 0.0)
        self.damping_mode = False
        self.u = np.zeros(nj)
        self.tau = np.zeros(nj)
        self._meas: tuple | None = None

    def rewind_clock(self) -> None:
        """Set simulation time to 0 without touching the state (after a settling pre-roll);
        the held command's stamp moves with the clock."""
        self._command = self._command._replace(stamp=self._command.stamp - float(self.data.time))
        self.set_time(0.0)
        self._meas = None
        self._forward_state = None

    def set_time(self, t: float) -> None:
        """Simulation time t [s] now (the state untouched): the clock runs on from t."""
        self._clock = (float(t), self._k)
        self.data.time = float(t)

    def _tick_clock(self) -> None:
        """data.time from the step count: mj_step's time += dt drifts (−1 ns after 350 s, −21 ns
        after 1,200 s), and a sample then falls on the other side of a gait's contact switch
        from the instant it is for (references.SWITCH_TOLERANCE)."""
        t0, k0 = self._clock
        self.data.time = t0 + (self._k - k0) * float(self.model.opt.timestep)

    def set_command(self, u_ff: np.ndarray, q_target: np.ndarray, qd_target: np.ndarray, kp: np.ndarray,
                    kd: np.ndarray, damping_mode: bool = False, stamp: float | None = None) -> None:
        """Hold a TorqueCommand until the next one; in damping mode u = −kd·q̇ only.

        `stamp`: the simulation time [s] the command was computed for (its header stamp;
        None: now); the joint loop's position target at time s is
        q_target + qd_target·(s − stamp) (module docstring, TorqueCommand.msg).
        Non-finite values or negative gains raise PlantError (nodes drop such commands
        before they get here; NaN never reaches the actuators).
        """
        nj = self.robot.n_joints
        try:
            fields = [np.ascontiguousarray(a, dtype=float) for a in (u_ff, q_target, qd_target, kp, kd)]
        except (TypeError, ValueError) as err:
            raise PlantError(f"command: expected {nj} numbers per field") from err
        if any(a.shape != (nj,) for a in fields):
            raise PlantError(f"command: expected {nj} values per field")
        stamp = self.time if stamp is None else float(stamp)
        if not math.isfinite(stamp):
            raise PlantError("command: non-finite stamp")
        c, c_rate, kp_j, kd_j = np.empty(nj), np.empty(nj), np.empty(nj), np.empty(nj)
        status = joint_loop.command_coefficients(*fields, bool(damping_mode), c, c_rate, kp_j, kd_j)
        if status:
            raise PlantError(f"command: expected {nj} finite values per field" if status == 1
                             else "command: negative stiffness or damping")
        self.damping_mode = bool(damping_mode)
        self._command = joint_loop.HeldCommand(c, c_rate, kp_j, kd_j, bool(c_rate.any()), stamp)

    # --- the 1 kHz joint loop -------------------------------------------------------------------
    def _encoder_noise(self, n: int) -> tuple[np.ndarray, np.ndarray, int]:
        """Encoder noise rows (q, q̇) of the next m ≤ n joint-loop readings from the current
        step (m up to the end of the current noise block; empty arrays without noise)."""
        if not self._encoder_noisy:
            return self._no_noise, self._no_noise, n
        i = self._k - self._noise_start
        if i >= _NOISE_BLOCK:
            nj = self.robot.n_joints
            self._noise_q = self.noise["q"] * self._rng_joint.standard_normal((_NOISE_BLOCK, nj))
            self._noise_qd = self.noise["qd"] * self._rng_joint.standard_normal((_NOISE_BLOCK, nj))
            self._noise_start, i = self._k, 0
        m = min(n, _NOISE_BLOCK - i)
        return self._noise_q[i:i + m], self._noise_qd[i:i + m], m

    def _actuation(self) -> joint_loop.JointReading:
        """(q_meas, q̇_meas, u, lag state, τ) at the current step under the held command
        (ciml_sim.joint_loop.actuation, the law the compiled loop runs)."""
        noise_q, noise_qd, _ = self._encoder_noise(1)
        none = np.empty(0)
        nj = self.robot.n_joints
        out = joint_loop.JointReading(*(np.empty(nj) for _ in range(5)))
        joint_loop.actuation(self._qj, self._vj, self._actuators, self._command, noise_q[0] if len(noise_q) else none,
                             noise_qd[0] if len(noise_qd) else none, float(self.data.time), out)
        return out

    def _friction_levels(self) -> list[np.ndarray]:
        """Current frictionloss levels of the effects that set one between steps (per effect)."""
        qd = self._vj
        return [SIM_EFFECTS[e.type].friction_level(e, qd[j]) for e, j in self.friction_levels]

    def _side_torques(self) -> list[np.ndarray]:
        """Explicit joint-side torques of the effects that set one between steps (per effect)."""
        q = self._qj
        return [SIM_EFFECTS[e.type].side_torque(e, q[j]) for e, j in self.side_effects]

    def _apply(self, tau: np.ndarray) -> None:
        """Actuator torque and the joint-side effects into MjData for the next evaluation."""
        self._ctrl[:] = tau
        if self.friction_levels:
            fl = self.coulomb.copy()
            for (e, j), level in zip(self.friction_levels, self._friction_levels()):
                fl[j] += level
            self.model.dof_frictionloss[6:] = fl
        if self._has_side:
            f = np.zeros(self.robot.n_joints)
            for (e, j), t in zip(self.side_effects, self._side_torques()):
                f[j] += t
            self._qfrc_j[:] = f

    def step(self, n: int = 1) -> None:
        """Advance n physics steps of 1 ms, running the joint loop at every step
        (compiled, ciml_sim.joint_loop; step by step in Python only for the effects
        evaluated between steps: Stribeck friction, springs, torque ripple)."""
        m, d = self.model, self.data
        # measure() left mj_forward's position and velocity stages of this very state in MjData
        reuse = (self._meas is not None and self._forward_state is not None
                 and self._forward_state == d.qpos.tobytes() + d.qvel.tobytes())
        done = 0
        while done < n:
            if self._extra:
                _, _, self.u, lag, self.tau = self._actuation()
                self._actuators.lag[:] = lag
                self._apply(self.tau)
                (mujoco.mj_step2 if reuse else mujoco.mj_step)(m, d)
                k = 1
            else:
                noise_q, noise_qd, k = self._encoder_noise(n - done)
                joint_loop.run_joint_loop(self._mujoco, k, reuse, float(d.time), float(m.opt.timestep), self._qj,
                                          self._vj, self._ctrl, self._actuators, self._command, noise_q, noise_qd,
                                          self.u, self.tau)
            reuse = False
            done += k
            self._k += k
        if n > 0:
            self._tick_clock()
            self._meas = None
            self._forward_state = None

    # --- the compiled closed loop (ciml_sim.joint_loop.closed_loop) --------------------------------
    @property
    def compiles_closed_loop(self) -> bool:
        """Whether joint_loop.closed_loop can run this plant: not with effects evaluated in
        Python between steps (Stribeck friction, springs, torque ripple)."""
        return not self._extra

    def compiled_state(self) -> joint_loop.PlantState:
        """The plant's state and parameters as joint_loop.closed_loop reads and updates
        them (arrays shared, updated in place); compiled_done() takes the scalars back."""
        m, d = self.model, self.data
        # the noise blocks in use (empty when none is drawn yet: closed_loop hands the tick back)
        i = self._k - self._noise_start
        if self._encoder_noisy and 0 <= i < _NOISE_BLOCK:
            enc_q, enc_qd = self._noise_q, self._noise_qd
        else:
            enc_q, enc_qd, i = self._no_noise, self._no_noise, 0
        if self._meas_noise_len and self._meas_noise_i < _NOISE_BLOCK:
            meas, meas_i = self._meas_noise, self._meas_noise_i
        else:
            meas, meas_i = np.empty((0, self._meas_noise_len)), 0
        return joint_loop.PlantState(
            mujoco=self._mujoco, qpos=d.qpos, qvel=d.qvel, qj=self._qj, vj=self._vj, ctrl=self._ctrl,
            actuators=self._actuators, command=self._command, sensors=self._sensors, noisy=self._encoder_noisy,
            enc_q=enc_q, enc_qd=enc_qd, enc_i=i, meas_noise=meas, meas_i=meas_i, u=self.u, tau=self.tau,
            dt=float(m.opt.timestep))

    def compiled_done(self, physics_steps: int, meas_i: int, stamp: float, has_rate: bool) -> None:
        """After joint_loop.closed_loop: the steps it ran, the measurement-noise position,
        the last command's stamp and rate flag."""
        self._k += physics_steps
        self._tick_clock()
        if self._meas_noise_len and self._meas_noise_i < _NOISE_BLOCK:  # a block was in use
            self._meas_noise_i = meas_i
        self._command = self._command._replace(stamp=float(stamp), has_rate=bool(has_rate))
        self.damping_mode = False
        self._meas = None
        self._forward_state = None

    # --- sensors ----------------------------------------------------------------------------
    def _measurement_noise(self) -> np.ndarray | None:
        """This sample's standard-normal draws of the enabled sensor noises (orientation,
        torque, position, twist, in that order), from blocks of _NOISE_BLOCK samples: the
        same numbers as drawing each sensor's noise at each sample."""
        if self._meas_noise_len == 0:
            return None
        i = self._meas_noise_i
        if i >= _NOISE_BLOCK:
            self._meas_noise = self._rng_meas.standard_normal((_NOISE_BLOCK, self._meas_noise_len))
            i = 0
        self._meas_noise_i = i + 1
        return self._meas_noise[i]

    def measure(self) -> Measurement:
        """Sensor readings at the current instant (cached until the next step)."""
        if self._meas is not None:
            return self._meas[0]
        q_m, qd_m, u, lag, tau = self._actuation()
        self._apply(tau)
        d = self.data
        nj, nf = self.robot.n_joints, self.robot.n_feet
        reading = joint_loop.SensorReading(np.empty(4), np.empty(3), np.empty(3), np.empty(3), np.empty(nj),
                                           np.empty((nf, 3)), np.empty(nf, dtype=np.bool_))
        z = self._measurement_noise()
        # mj_forward: accelerations and contact forces at t under τ(t); then the sensors
        joint_loop.sense(self._mujoco, d.qpos, d.qvel, self._sensors, self._no_sample_noise if z is None else z, tau,
                         reading)
        quat, pos, lin, ang, tau_meas, forces, contacts = reading
        self._forward_state = d.qpos.tobytes() + d.qvel.tobytes()
        meas = Measurement(time=float(d.time), q=q_m, qd=qd_m, tau_measured=tau_meas, u_commanded=u.copy(),
                           base_position=pos, base_orientation=quat, base_linear_velocity=lin,
                           base_angular_velocity=ang, contacts=contacts)
        self._meas = (meas, u, lag, tau, forces)
        return meas

    def ground_truth(self) -> GroundTruth:
        """True state, v̇, contact forces and each effect's generalized force at this instant
        (same instant and torque as measure(); see the module docstring)."""
        if self._meas is None:
            self.measure()
        assert self._meas is not None  # measure() holds it
        _, u, lag, tau, forces = self._meas
        d = self.data
        # mjcf.mj_to_pin_state / mj_to_pin_acceleration, inlined (same arithmetic, no np.cross)
        qpos, qvel = d.qpos, d.qvel
        quat = qpos[[4, 5, 6, 3]]
        quat /= math.sqrt(quat @ quat)
        R = quat_xyzw_to_matrix(quat)
        q = np.concatenate([qpos[:3], quat, qpos[7:]])
        v = np.concatenate([R.T @ qvel[:3], qvel[3:]])
        vdot = np.array(d.qacc, dtype=float)
        w, vl = v[3:6], v[:3]
        vdot[:3] = R.T @ d.qacc[:3] - np.array([w[1] * vl[2] - w[2] * vl[1], w[2] * vl[0] - w[0] * vl[2],
                                                 w[0] * vl[1] - w[1] * vl[0]])
        nv = self.robot.nv
        share = levels = None
        if self._gt_friction:
            # joint friction constraint forces, shared among the effects by their current levels
            friction = np.zeros(nv)
            rows = d.efc_type[: d.nefc] == _FRICTION_DOF  # one row per DOF with friction loss
            friction[d.efc_id[: d.nefc][rows]] = d.efc_force[: d.nefc][rows]
            level = self.coulomb.copy()
            current = self._friction_levels()
            for (e, j), lv in zip(self.friction_levels, current):
                level[j] += lv
            share = np.divide(friction[6:], level, out=np.zeros_like(level), where=level > 0)
            levels = dict(zip((id(e) for e, _ in self.friction_levels), current))
        side = dict(zip((id(e) for e, _ in self.side_effects), self._side_torques())) if self._has_side else {}
        lag_share = np.divide(lag - u, self.lag_time_constant, out=np.zeros_like(u), where=self.lag_time_constant > 0)
        inertial_of = {id(e): (m, md) for e, m, md in self._inertial}
        nominal_id = pin.rnea(self.robot.model, self._nominal_data, q, v, vdot) if self._inertial else None

        def inertial_force(e: Effect) -> np.ndarray:
            m, md = inertial_of[id(e)]
            return -(pin.rnea(m, md, q, v, vdot) - nominal_id)

        truth = Truth(nv, self._vj, u, lag, share, levels or {}, side, lag_share, inertial_force)
        effects: dict[str, np.ndarray] = {}
        for e, j in self._gt_effects:
            f = SIM_EFFECTS[e.type].force(truth, e, j)
            if f is not None:  # measurement effects exert none
                effects[e.label] = f
        return GroundTruth(q=q, v=v, vdot=vdot, contact_forces=forces.copy(), u=u.copy(), tau=tau.copy(),
                           effect_forces=effects)

