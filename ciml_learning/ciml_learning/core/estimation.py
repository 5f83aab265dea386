"""Estimators for the roles a robot's log may leave out: the base state and the contacts.

Many robots log no base odometry and no contact flags: a Unitree-like robot logs an IMU and
per-foot pressure sensors, a ros2_control robot joint states and an IMU only. The contact-
invariant extraction (eq. 3, 17) needs the base state (q, v of the free-flyer) and the stance
set; this module supplies them from what is logged. Pure numpy/Pinocchio, array in, array out
(no rclpy); the log readers (bagio) call it when a profile says `estimate:` for a role
(docs/ROBOT_PROFILE.md).

- `estimate_base`: orientation from the IMU (rotated into the base frame when the IMU sits
  in another frame), angular velocity = the gyro, linear velocity from the stance feet: a
  foot in contact does not move, so in the base frame

      0 = v_b + ω × r_f + J_f q̇_j   ⇒   v_b = −(J_f q̇_j + ω × r_f),

  averaged over the stance feet (r_f the foot position and J_f the leg's foot Jacobian, both
  in the base frame). Position: height from the stance feet on flat ground at z = 0, x and y
  integrated from the velocity. The learning inputs exclude base position and yaw (the
  dynamics of eq. 3 do not depend on them), so the integrator's drift and an IMU's yaw drift
  do not reach the model error.
- `AttitudeFilter` / `estimate_orientation`: the IMU's orientation from its gyro and
  accelerometer, for drivers that never fill the quaternion — Mahony's explicit complementary
  filter (R. Mahony, T. Hamel, J.-M. Pflimlin, "Nonlinear Complementary Filters on the Special
  Orthogonal Group", IEEE TAC 53(5), 2008, §V-B): the gyro is integrated on SO(3) and the
  accelerometer's direction (gravity, up to the base's own acceleration) pulls the estimated
  "up" towards it with the bandwidth ATTITUDE_KP, an integral term taking out a gyro bias.
  Roll and pitch are observable; yaw is the gyro's integral (it starts at 0 and drifts), which
  the learning inputs exclude (eq. 12).
- `estimate_contacts`: each foot's ground reaction from its leg's rows of eq. (3): for the
  joints of leg l only foot l's contact Jacobian is non-zero, so

      (M q̇̇ + h)_l − τ_l = J_lᵀ λ_l   ⇒   λ_l = J_l⁻ᵀ ((M q̈ + h)_l − τ_l),

  with q̈ differentiated from q̇ (Savitzky–Golay, scipy); the normal force λ_l,z (world z, up)
  is thresholded with hysteresis (`threshold_contacts`), optionally gated by the foot's speed.
  Model errors (friction, payload, actuator effects) bias λ by the same error the diagnosis
  looks for; the thresholds sit well above them (fractions of the robot's weight).
- `contact_agreement`: per-foot agreement of two contact sequences, for reports.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin
from scipy.signal import savgol_filter

from ciml_learning.core.dynamics import quaternion_xyzw
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription

GRAVITY = 9.81  # [m/s²]
CONTACT_THRESHOLD_WEIGHT = 0.15
"""Default contact threshold of the dynamics estimate: this fraction of the robot's weight
per foot (a stance foot of a trotting quadruped carries ~0.25–0.5 of it, a swing foot ~0)."""
CONTACT_HYSTERESIS_WEIGHT = 0.11
"""Default hysteresis of the dynamics estimate, as a fraction of the robot's weight."""
DERIVATIVE_WINDOW_S = 0.03
"""[s] Savitzky–Golay window for q̈ (quadratic fit): short against a 0.27 s trot swing."""


ATTITUDE_KP = 1.0
"""[1/s] proportional gain of the attitude filter: the accelerometer corrects the gyro's tilt with a
1 s time constant, far slower than a gait (1.5–3 Hz), so the base's own accelerations over a stride
average out, and fast enough that a gyro bias b leaves a tilt of only b / ATTITUDE_KP before the
integral term removes it."""
ATTITUDE_KI = 0.1
"""[1/s²] integral gain of the attitude filter (gyro bias): with ATTITUDE_KP an overdamped loop
(s² + KP s + KI, ζ ≈ 1.6) whose slow pole (0.113 s⁻¹) learns a constant bias in ≈ 9 s. On a
simulated go1 trot with a 0.015 rad/s gyro bias, KP = 1 / KI = 0.1 gave the smallest tilt error
of KP 0.3–5 (0.93° rms; 1.93° at KP 0.3, 1.16° at KP 5: docs/ROBOT_PROFILE.md)."""
ATTITUDE_INIT_S = 0.1
"""[s] the first accelerometer readings averaged for the initial tilt (yaw starts at 0)."""


class EstimationError(CimlError):
    """The arrays given to an estimator cannot be used (sizes, non-finite, too short)."""


def _check_rows(name: str, x: np.ndarray, n: int, cols: int) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim != 2 or x.shape != (n, cols):
        raise EstimationError(f"{name}: expected shape ({n}, {cols}), got {x.shape}")
    return x


class Hysteresis:
    """threshold_contacts one sample at a time (the state carries over), so a node and the log
    reader run the same law: step(force row) → flags."""

    def __init__(self, threshold: float, hysteresis: float, n_feet: int) -> None:
        if not (np.isfinite(threshold) and np.isfinite(hysteresis) and hysteresis >= 0):
            raise EstimationError(f"threshold {threshold} and hysteresis {hysteresis} must be finite, hysteresis ≥ 0")
        self.on_level, self.off_level = float(threshold), float(threshold) - float(hysteresis)
        self.state = np.zeros(n_feet, dtype=bool)

    def step(self, force: np.ndarray) -> np.ndarray:
        f = np.asarray(force, dtype=float)  # NaN compares False both ways: the state is kept
        self.state = np.where(f >= self.on_level, True, np.where(f < self.off_level, False, self.state))
        return self.state.copy()


def threshold_contacts(force: np.ndarray, threshold: float, hysteresis: float = 0.0) -> np.ndarray:
    """Contact flags from per-foot forces (or pressures) with a hysteresis band.

    A foot turns on when its force rises to `threshold` or above, and off when it falls below
    `threshold − hysteresis`; in between it keeps its state (so noise around one threshold
    does not chatter). The first sample is on if at or above `threshold`. A non-finite force
    keeps the previous state (off at the start).

    force: (N × n_feet) in any unit, threshold and hysteresis in the same unit (hysteresis ≥ 0).
    Returns (N × n_feet) bool.
    """
    f = np.asarray(force, dtype=float)
    if f.ndim == 1:
        f = f[:, None]
    if f.ndim != 2:
        raise EstimationError(f"force: expected (N × n_feet), got shape {np.shape(force)}")
    band = Hysteresis(threshold, hysteresis, f.shape[1])
    return np.array([band.step(row) for row in f], dtype=bool).reshape(f.shape)


def contact_agreement(a: np.ndarray, b: np.ndarray, feet: Sequence[str] | None = None) -> dict:
    """Agreement of two contact sequences (N × n_feet bool), e.g. an estimate and a sensor.

    Returns {"overall": fraction of equal flags, "per_foot": {foot: fraction},
    "samples": N, "a_only": {foot: fraction of samples a says contact and b not},
    "b_only": {...}} (feet named `feet`, else foot_0 …).
    """
    a, b = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    if a.shape != b.shape or a.ndim != 2:
        raise EstimationError(f"contact sequences must have the same (N × n_feet) shape, got {a.shape} and {b.shape}")
    names = list(feet) if feet is not None else [f"foot_{i}" for i in range(a.shape[1])]
    if len(names) != a.shape[1]:
        raise EstimationError(f"{len(names)} foot names for {a.shape[1]} feet")
    n = max(len(a), 1)
    same = (a == b).sum(axis=0) / n
    return {
        "overall": float((a == b).mean()) if len(a) else float("nan"),
        "per_foot": {f: float(x) for f, x in zip(names, same)},
        "a_only": {f: float(x) for f, x in zip(names, (a & ~b).sum(axis=0) / n)},
        "b_only": {f: float(x) for f, x in zip(names, (~a & b).sum(axis=0) / n)},
        "samples": int(len(a)),
    }


def _frame_rotation(robot: RobotDescription, frame: str | None) -> np.ndarray:
    """R_base_frame (3 × 3): orientation of a URDF frame fixed to the base, in the base frame."""
    if frame is None:
        return np.eye(3)
    model = robot.model
    if not model.existFrame(frame):
        raise EstimationError(f"IMU frame {frame!r} is not a frame of the URDF")
    fid = model.getFrameId(frame)
    if model.frames[fid].parentJoint != 1:
        raise EstimationError(f"IMU frame {frame!r} is not fixed to the base (it moves with a leg joint)")
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    return data.oMf[fid].rotation.copy()


def _normalized_quat(quat_xyzw: np.ndarray, name: str) -> np.ndarray:
    n = np.linalg.norm(quat_xyzw, axis=1, keepdims=True)
    if not np.all(np.isfinite(quat_xyzw)) or np.any(n < 1e-6):
        bad = int(np.flatnonzero(~np.isfinite(n[:, 0]) | (n[:, 0] < 1e-6))[0])
        raise EstimationError(f"{name}: zero or non-finite quaternion at sample {bad}")
    return quat_xyzw / n


def _tilt(accel: np.ndarray) -> np.ndarray:
    """R_world_imu of roll and pitch from the accelerometer's direction at rest, yaw 0 (ZYX)."""
    ax, ay, az = accel
    return pin.rpy.rpyToMatrix(np.arctan2(ay, az), np.arctan2(-ax, np.hypot(ay, az)), 0.0)


class AttitudeFilter:
    """Mahony's explicit complementary filter (module docstring): one IMU sample at a time, so a
    node and the log reader run the same law.

    update(dt, gyro, accel): dt [s] since the previous sample, gyro [rad/s] and accel [m/s², the
    specific force, REP 145: gravity included] in the IMU frame; returns R_world_imu (3 × 3).
    """

    def __init__(self, accel0: np.ndarray, kp: float = ATTITUDE_KP, ki: float = ATTITUDE_KI) -> None:
        a = np.asarray(accel0, dtype=float)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 0.5 * GRAVITY:
            raise EstimationError(f"initial accelerometer reading {a} is not gravity (|a| ≥ {0.5 * GRAVITY} m/s²)")
        self.kp, self.ki = float(kp), float(ki)
        self.R = _tilt(a)
        self.bias_correction = np.zeros(3)   # the integral term: −(estimated gyro bias) [rad/s]

    def update(self, dt: float, gyro: np.ndarray, accel: np.ndarray) -> np.ndarray:
        omega = np.asarray(gyro, dtype=float)
        a = np.asarray(accel, dtype=float)
        n = float(np.linalg.norm(a))
        if n > 0.1 * GRAVITY:  # a free-falling or silent accelerometer says nothing about "up"
            err = np.cross(a / n, self.R[2])   # measured × estimated up, IMU frame (Mahony §V-B, ω_mes)
            self.bias_correction += self.ki * err * dt
            omega = omega + self.kp * err + self.bias_correction
        if dt > 0:
            self.R = self.R @ pin.exp3(omega * dt)
        return self.R


class OrientationEstimator:
    """AttitudeFilter on a stream of IMU samples, started as estimate_orientation starts it: the
    samples of the first ATTITUDE_INIT_S are held until the initial tilt (their mean accelerometer
    reading) is known, then every sample comes out in order with its orientation.

    push(t [s], gyro [rad/s], accel [m/s²]) → [(t, quaternion x y z w), ...] (empty while held).
    Each step integrates the mean of its two gyro readings.
    """

    def __init__(self, kp: float = ATTITUDE_KP, ki: float = ATTITUDE_KI) -> None:
        self.kp, self.ki = kp, ki
        self.filter: AttitudeFilter | None = None
        self._held: list[tuple[float, np.ndarray, np.ndarray]] = []
        self._last: tuple[float, np.ndarray] | None = None  # (t, gyro) of the previous sample

    def push(self, t: float, gyro: np.ndarray, accel: np.ndarray) -> list[tuple[float, np.ndarray]]:
        sample = (float(t), np.asarray(gyro, dtype=float), np.asarray(accel, dtype=float))
        if not (np.isfinite(sample[0]) and np.all(np.isfinite(sample[1])) and np.all(np.isfinite(sample[2]))):
            raise EstimationError("non-finite IMU or time sample")
        if self.filter is None:
            if not self._held or sample[0] <= self._held[0][0] + ATTITUDE_INIT_S:
                self._held.append(sample)
                return []
            held, self._held = self._held, []
            self.filter = AttitudeFilter(np.mean([a for _, _, a in held], axis=0), self.kp, self.ki)
            return [self._step(*s) for s in (*held, sample)]
        return [self._step(*sample)]

    def flush(self) -> list[tuple[float, np.ndarray]]:
        """The held samples of a stream shorter than ATTITUDE_INIT_S (a whole log read at once)."""
        if self.filter is not None or not self._held:
            return []
        held, self._held = self._held, []
        self.filter = AttitudeFilter(np.mean([a for _, _, a in held], axis=0), self.kp, self.ki)
        return [self._step(*s) for s in held]

    def _step(self, t: float, gyro: np.ndarray, accel: np.ndarray) -> tuple[float, np.ndarray]:
        assert self.filter is not None
        if self._last is not None:
            self.filter.update(t - self._last[0], 0.5 * (self._last[1] + gyro), accel)
        self._last = (t, gyro)
        return t, quaternion_xyzw(self.filter.R)


def estimate_orientation(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, kp: float = ATTITUDE_KP,
                         ki: float = ATTITUDE_KI) -> np.ndarray:
    """The IMU's orientation (N × 4, x y z w; world z up, yaw 0 at the start) from its gyro
    (N × 3) [rad/s] and accelerometer (N × 3) [m/s², gravity included] at stamps t (N) [s]
    (OrientationEstimator: the initial tilt from the first ATTITUDE_INIT_S of accelerometer readings)."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    gyro = _check_rows("gyro", gyro, n, 3)
    accel = _check_rows("accel", accel, n, 3)
    if n == 0:
        raise EstimationError("no IMU samples")
    est = OrientationEstimator(kp, ki)
    out = [q for k in range(n) for _, q in est.push(t[k], gyro[k], accel[k])] + [q for _, q in est.flush()]
    return np.array(out)


def estimate_base(
    robot: RobotDescription,
    t: np.ndarray,
    q_joints: np.ndarray,
    qd_joints: np.ndarray,
    imu_quat_xyzw: np.ndarray,
    imu_gyro: np.ndarray,
    contacts: np.ndarray,
    imu_frame: str | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Base pose and twist from an IMU and the stance legs' kinematics.

    t (N) [s]; q_joints, qd_joints (N × n_j) in the robot's joint order [rad, rad/s];
    imu_quat_xyzw (N × 4) orientation of the IMU frame in a gravity-aligned world frame;
    imu_gyro (N × 3) the IMU frame's angular velocity in the IMU frame [rad/s]; contacts
    (N × n_feet) stance flags; imu_frame: the URDF frame the IMU is mounted in (fixed to the
    base), None when the IMU frame is the base frame.

    Returns (base_pos (N × 3) [m, world], base_quat_xyzw (N × 4), base_twist_body (N × 6):
    linear [m/s] then angular [rad/s], in the base frame — Pinocchio's free-flyer v[:6]).
    A sample with no stance foot (flight, or every contact flag off) keeps the previous
    linear velocity (the first stance sample's before the first stance); the height is
    held likewise.
    """
    t = np.asarray(t, dtype=float)
    n, nj, nf = len(t), robot.n_joints, robot.n_feet
    qj = _check_rows("q_joints", q_joints, n, nj)
    qdj = _check_rows("qd_joints", qd_joints, n, nj)
    quat = _normalized_quat(_check_rows("imu_quat_xyzw", imu_quat_xyzw, n, 4), "imu_quat_xyzw")
    gyro = _check_rows("imu_gyro", imu_gyro, n, 3)
    contacts = np.asarray(contacts, dtype=bool)
    if contacts.shape != (n, nf):
        raise EstimationError(f"contacts: expected shape ({n}, {nf}), got {contacts.shape}")
    if n == 0:
        raise EstimationError("no samples")
    if not (np.all(np.isfinite(qj)) and np.all(np.isfinite(qdj)) and np.all(np.isfinite(gyro))
            and np.all(np.isfinite(t))):
        raise EstimationError("non-finite joint, gyro or time samples")
    legs = LegOdometry(robot, imu_frame)
    quat_b = np.array([legs.base_quat(q) for q in quat])
    omega = gyro @ legs.R_bi.T
    lin = np.full((n, 3), np.nan)
    height = np.full(n, np.nan)
    for k in range(n):
        found = legs.stance(qj[k], qdj[k], quat_b[k], omega[k], contacts[k])
        if found is not None:
            lin[k], height[k] = found
    valid = np.flatnonzero(np.isfinite(lin[:, 0]))
    if len(valid) == 0:
        raise EstimationError("no sample has a stance foot: the base velocity cannot be estimated from the legs")
    # hold the last stance estimate through flight phases (and back-fill before the first)
    idx = np.maximum.accumulate(np.where(np.isfinite(lin[:, 0]), np.arange(n), -1))
    idx[idx < 0] = valid[0]
    lin, height = lin[idx], height[idx]
    # x, y: trapezoidal integration of the world-frame velocity; z: the stance legs' height
    v_world = np.einsum("kij,kj->ki", _rotations(quat_b), lin)
    pos = np.zeros((n, 3))
    if n > 1:
        dt = np.diff(t)[:, None]
        pos[1:, :2] = np.cumsum(0.5 * (v_world[1:, :2] + v_world[:-1, :2]) * dt, axis=0)
    pos[:, 2] = height
    return pos, quat_b, np.hstack([lin, omega])


class LegOdometry:
    """The base from an IMU and the stance legs (estimate_base's law), one sample at a time.

    base_quat / stance are the per-sample law estimate_base applies to a whole log; step() is its
    causal form for a node: a sample without a stance foot holds the previous linear velocity and
    height (None before the first stance: a stream cannot back-fill), and x, y integrate the
    world-frame velocity trapezoidally from the first sample out.
    """

    def __init__(self, robot: RobotDescription, imu_frame: str | None = None) -> None:
        self.robot = robot
        self.R_bi = _frame_rotation(robot, imu_frame)
        self._data = robot.model.createData()
        self._q = pin.neutral(robot.model)  # base at the origin, level: kinematics in the base frame
        self._v = np.zeros(robot.model.nv)
        self._last: tuple[float, np.ndarray, np.ndarray] | None = None  # t, world velocity, x y of the last step
        self._held: tuple[np.ndarray, float] = (np.zeros(3), 0.0)  # the last stance estimate

    def base_quat(self, imu_quat_xyzw: np.ndarray) -> np.ndarray:
        """The base orientation R_wb = R_wi R_ib (x y z w) of the IMU's."""
        return quaternion_xyzw(pin.Quaternion(np.asarray(imu_quat_xyzw, dtype=float)).matrix() @ self.R_bi.T)

    def stance(self, qj: np.ndarray, qdj: np.ndarray, quat_b: np.ndarray, omega_b: np.ndarray,
               contacts: np.ndarray) -> tuple[np.ndarray, float] | None:
        """(linear velocity [m/s] in the base frame, height [m]) from the stance feet (module
        docstring), None without a stance foot."""
        stance = np.flatnonzero(contacts)
        if len(stance) == 0:
            return None
        model, data, q, v = self.robot.model, self._data, self._q, self._v
        q[7:] = qj
        v[3:6], v[6:] = omega_b, qdj
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        R_wb = pin.Quaternion(quat_b).matrix()
        vel, z = np.zeros(3), 0.0
        for i in stance:
            fid = self.robot.foot_frame_ids[i]
            # foot velocity with the base at rest linearly: ω × r_f + J_f q̇_j (base frame)
            vel -= pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
            z -= (R_wb @ data.oMf[fid].translation)[2]
        return vel / len(stance), z / len(stance)

    def step(self, t: float, qj: np.ndarray, qdj: np.ndarray, imu_quat_xyzw: np.ndarray, imu_gyro: np.ndarray,
             contacts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(base position (3), quaternion x y z w (4), twist in the base frame (6)) at t [s], or
        None before the first stance sample."""
        quat_b = self.base_quat(imu_quat_xyzw)
        omega = self.R_bi @ np.asarray(imu_gyro, dtype=float)
        found = self.stance(qj, qdj, quat_b, omega, contacts)
        if found is None:
            if self._last is None:
                return None
            found = self._held  # flight: the last stance estimate, as estimate_base holds it
        lin, height = found
        v_world = pin.Quaternion(quat_b).matrix() @ lin
        xy = np.zeros(2) if self._last is None else (
            self._last[2] + 0.5 * (v_world[:2] + self._last[1][:2]) * (t - self._last[0]))
        self._last, self._held = (float(t), v_world, xy), found
        return np.r_[xy, height], quat_b, np.r_[lin, omega]


def _rotations(quat_xyzw: np.ndarray) -> np.ndarray:
    """(N × 3 × 3) rotation matrices of unit quaternions (x, y, z, w)."""
    x, y, z, w = quat_xyzw.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=-1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=-1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=1)


def differentiate(t: np.ndarray, x: np.ndarray, window_s: float = DERIVATIVE_WINDOW_S) -> np.ndarray:
    """dx/dt of rows sampled at t (Savitzky–Golay, quadratic, window `window_s` at the median
    rate; ≥ 5 samples). The log is taken as uniformly sampled at its median interval."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if len(t) < 5:
        raise EstimationError(f"need at least 5 samples to differentiate, got {len(t)}")
    dt = float(np.median(np.diff(t)))
    if not dt > 0:
        raise EstimationError("time stamps do not increase")
    win = max(5, int(round(window_s / dt)) | 1)
    win = min(win, len(t) if len(t) % 2 else len(t) - 1)
    return savgol_filter(x, win, 2, deriv=1, delta=dt, axis=0, mode="interp")


def leg_forces(robot: RobotDescription, t: np.ndarray, q: np.ndarray, v: np.ndarray, tau: np.ndarray,
               a: np.ndarray | None = None) -> np.ndarray:
    """Ground reaction force on each foot from its leg's rows of eq. (3), (N × n_feet × 3) [N],
    world-aligned (z up). a: generalized accelerations (N × nv); differentiated from v if None."""
    t = np.asarray(t, dtype=float)
    n = len(t)
    q = _check_rows("q", q, n, robot.nq)
    v = _check_rows("v", v, n, robot.nv)
    tau = _check_rows("tau", tau, n, robot.n_joints)
    a = differentiate(t, v) if a is None else _check_rows("a", a, n, robot.nv)
    model, data = robot.model, robot.model.createData()
    legs = [np.asarray(leg, dtype=int) for leg in robot.leg_joints]
    out = np.full((n, robot.n_feet, 3), np.nan)
    for k in range(n):
        if not (np.all(np.isfinite(q[k])) and np.all(np.isfinite(v[k])) and np.all(np.isfinite(a[k]))
                and np.all(np.isfinite(tau[k]))):
            continue
        qk = q[k].copy()
        qk[3:7] /= np.linalg.norm(qk[3:7])
        rhs = pin.rnea(model, data, qk, v[k], a[k])[6:] - tau[k]   # (M q̈ + h − Sᵀτ), joint rows
        pin.computeJointJacobians(model, data, qk)
        pin.updateFramePlacements(model, data)
        for i, (fid, leg) in enumerate(zip(robot.foot_frame_ids, legs)):
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3, 6 + leg]
            # J_lᵀ λ = rhs_l; least squares so that a stretched (singular) leg gives a finite answer
            out[k, i] = np.linalg.lstsq(J.T, rhs[leg], rcond=1e-6)[0]
    return out


def estimate_contacts(
    robot: RobotDescription,
    t: np.ndarray,
    q: np.ndarray,
    v: np.ndarray,
    tau: np.ndarray,
    threshold: float | None = None,
    hysteresis: float | None = None,
    max_foot_speed: float | None = None,
    a: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Contact flags from the legs' dynamics (no force sensor).

    t (N) [s]; q (N × nq), v (N × nv) Pinocchio configuration and velocity (base twist in the
    base frame; from odometry or `estimate_base`); tau (N × n_j) measured joint torques [Nm].
    threshold, hysteresis [N]: on/off band of the normal force (`threshold_contacts`); default
    CONTACT_THRESHOLD_WEIGHT and CONTACT_HYSTERESIS_WEIGHT of the robot's weight.
    max_foot_speed [m/s]: if given, a foot moving faster than this (world frame) is not in
    contact whatever its force (needs a base twist one can trust; leave None otherwise).

    Returns (contacts (N × n_feet) bool, normal_force (N × n_feet) [N], upward on the robot).
    """
    weight = robot.total_mass * GRAVITY
    threshold = CONTACT_THRESHOLD_WEIGHT * weight if threshold is None else float(threshold)
    hysteresis = CONTACT_HYSTERESIS_WEIGHT * weight if hysteresis is None else float(hysteresis)
    forces = leg_forces(robot, t, q, v, tau, a)
    normal = forces[:, :, 2]
    contacts = threshold_contacts(normal, threshold, hysteresis)
    if max_foot_speed is not None:
        model, data = robot.model, robot.model.createData()
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        for k in range(len(q)):
            qk = q[k].copy()
            qk[3:7] /= np.linalg.norm(qk[3:7])
            pin.forwardKinematics(model, data, qk, v[k])
            pin.updateFramePlacements(model, data)
            for i, fid in enumerate(robot.foot_frame_ids):
                speed = np.linalg.norm(pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear)
                if speed > max_foot_speed:
                    contacts[k, i] = False
    return contacts, normal
