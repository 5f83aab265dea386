"""Full-body reference motions (paper §V-B): base-only, static walk and trot.

Each motion is a base trajectory (world position p(t), roll-pitch-yaw φ(t), with their
first and second time derivatives) and a trajectory per foot (world position, velocity,
acceleration) with a contact schedule. Leg inverse kinematics with Pinocchio turns them
into the full-body reference (qᵈ, q̇ᵈ, q̈ᵈ) in Pinocchio's free-flyer convention:

    q̇ᵈ_leg = J_leg⁻¹ (ṗ_foot − J_base v_base)
    q̈ᵈ_leg = J_leg⁻¹ (p̈_foot − J_base a_base − J̇ q̇ᵈ)

with v_base = (Rᵀṗ, ω) the base twist in the base frame and a_base = d/dt v_base =
(Rᵀp̈ − ω × Rᵀṗ, ω̇). Stance feet stay at their foothold, so J q̇ᵈ = 0 there and the
contact constraints of the inverse-dynamics QP hold along the reference.

Motions (step lengths are the displacement per gait cycle, as in the paper):
- `stand`: the standing pose, all feet in contact.
- `base_only`: periodic cubic spline (scipy, C²) through waypoints of the base pose,
  feet fixed; the offset from the standing pose fades in over the first second.
- `walk_*`: static walk (crawl). One leg swings at a time; a cycle is
  [shift][swing][swing][shift][swing][swing]: the two legs of one side (trailing leg
  first) swing back to back while the CoM rests in the intersection of their two
  support triangles (with a margin), the base shifts only while all four feet stand.
- `trot_*`: diagonal pairs swing together, short four-foot support at each switch; the
  base moves at constant velocity after a C² velocity ramp.
Every gait starts with a settle phase (all feet down) in which the base moves from the
standing pose to the pose that puts the CoM over the centre of the feet.

Footholds are placed under the hips at the middle of the following stance (relative to
a nominal progression x̄(t) of the CoM), so feet travel symmetrically about their
standing position. Swing feet follow a quintic (minimum-jerk) horizontal path and a
vertical bump h·64 s³(1−s)³: zero velocity and acceleration at lift-off and touch-down,
so qᵈ is C² across contact changes.

Nothing here assumes HyQ: legs, feet and the standing pose come from the robot
description and the q_stand argument.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.interpolate import CubicSpline
from scipy.optimize import linprog

from ciml_learning.errors import CimlError
from ciml_learning.robot import RobotDescription

from . import kernels


class ReferenceError_(CimlError):
    """Base of reference-generation errors (unknown motion, unreachable foot target)."""


class UnknownMotionError(ReferenceError_):
    """The motion name is not one of MOTIONS."""


class InverseKinematicsError(ReferenceError_):
    """A foot target cannot be reached by its leg."""


MOTIONS: tuple[str, ...] = (
    "stand", "base_only", "walk_20", "walk_30", "walk_35",
    "walk_rear_30", "walk_side_25", "trot_20", "trot_35", "trot_45",
)


@dataclass
class ReferencePoint:
    """One sample of a full-body reference.

    q: (nq) Pinocchio configuration; v: (nv) and a: (nv) generalized velocity and
    acceleration (base twist / its time derivative in the base frame); contacts:
    (n_feet,) contact schedule (True = stance); phase: gait phase in [0, 1).
    """

    t: float
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    contacts: np.ndarray
    phase: float
    motion: str


@dataclass(frozen=True)
class MotionSpec:
    kind: str                       # stand | base_only | walk | trot
    step_length: float = 0.0        # [m] per gait cycle
    direction: tuple[float, float] = (1.0, 0.0)
    period: float = 1.0             # [s] gait cycle
    step_height: float = 0.0        # [m]


SETTLE_TIME = 1.0
"""[s] all-feet-down phase at the start of a gait (base moves to the balanced pose)."""
WALK_PERIOD = 4.0
WALK_SHIFT = 0.8        # [s] each of the two base shifts per walk cycle
WALK_SWING = 0.6        # [s] each of the four swings per walk cycle (2·0.8 + 4·0.6 = 4.0)
WALK_MARGIN = 0.06      # [m] distance of the CoM target from the support triangles' edges
TROT_PERIOD = 0.6
TROT_SWING = 0.27       # [s] per diagonal pair; 0.03 s four-foot support at each switch
TROT_RAMP = 2.0         # [s] C² velocity ramp
BASE_ONLY_PERIOD = 5.0

SPECS: dict[str, MotionSpec] = {
    "stand": MotionSpec("stand"),
    "base_only": MotionSpec("base_only", period=BASE_ONLY_PERIOD),
    "walk_20": MotionSpec("walk", 0.20, (1.0, 0.0), WALK_PERIOD, 0.10),
    "walk_30": MotionSpec("walk", 0.30, (1.0, 0.0), WALK_PERIOD, 0.10),
    "walk_35": MotionSpec("walk", 0.35, (1.0, 0.0), WALK_PERIOD, 0.10),
    "walk_rear_30": MotionSpec("walk", 0.30, (-1.0, 0.0), WALK_PERIOD, 0.10),
    "walk_side_25": MotionSpec("walk", 0.25, (0.0, 1.0), WALK_PERIOD, 0.10),
    "trot_20": MotionSpec("trot", 0.20, (1.0, 0.0), TROT_PERIOD, 0.08),
    "trot_35": MotionSpec("trot", 0.35, (1.0, 0.0), TROT_PERIOD, 0.08),
    "trot_45": MotionSpec("trot", 0.45, (1.0, 0.0), TROT_PERIOD, 0.08),
}
assert tuple(SPECS) == MOTIONS

# base-only waypoints: offsets (x, y, z [m], roll, pitch, yaw [rad]) from the standing pose,
# one per second, periodic (the last equals the first)
BASE_ONLY_WAYPOINTS = np.array([
    [0.00, 0.00, 0.00, 0.00, 0.00, 0.00],
    [0.05, 0.03, -0.04, 0.06, 0.00, 0.08],
    [-0.02, -0.05, 0.02, -0.06, 0.07, 0.00],
    [-0.05, 0.02, -0.05, 0.00, -0.07, -0.08],
    [0.02, -0.03, 0.01, 0.05, 0.04, 0.05],
    [0.00, 0.00, 0.00, 0.00, 0.00, 0.00],
])


def spec(motion: str) -> MotionSpec:
    try:
        return SPECS[motion]
    except (KeyError, TypeError):
        raise UnknownMotionError(f"unknown motion {motion!r}; valid motions: {', '.join(MOTIONS)}") from None


def default_duration(motion: str) -> float:
    """Duration of a standard run [s]: 10 gait cycles after the settle phase; stand and
    base_only 20 s."""
    s = spec(motion)
    if s.kind in ("stand", "base_only"):
        return 20.0
    return SETTLE_TIME + 10.0 * s.period


# --- scalar profiles -----------------------------------------------------------------------


def quintic(s: float) -> tuple[float, float, float]:
    """Minimum-jerk blend 10s³ − 15s⁴ + 6s⁵ on [0, 1] and its first two derivatives
    (clamped outside): zero velocity and acceleration at both ends."""
    if s <= 0.0:
        return 0.0, 0.0, 0.0
    if s >= 1.0:
        return 1.0, 0.0, 0.0
    return (s ** 3 * (10 - 15 * s + 6 * s * s), 30 * s * s * (1 - s) ** 2, 60 * s * (1 - s) * (1 - 2 * s))


def bump(s: float) -> tuple[float, float, float]:
    """64 s³(1−s)³ (peak 1 at s = ½) and derivatives; zero outside [0, 1]."""
    if s <= 0.0 or s >= 1.0:
        return 0.0, 0.0, 0.0
    w = s * (1 - s)
    dw = 1 - 2 * s
    return 64 * w ** 3, 192 * w * w * dw, 192 * (2 * w * dw * dw - 2 * w * w)


def ramp_distance(t: float, v_nom: float, t_ramp: float) -> tuple[float, float, float]:
    """Progression x̄(t) with velocity v_nom·quintic(t/t_ramp): (x̄, ẋ̄, ẍ̄) for t ≥ 0."""
    if t <= 0.0:
        return 0.0, 0.0, 0.0
    if t >= t_ramp:
        return v_nom * (t - 0.5 * t_ramp), v_nom, 0.0
    s = t / t_ramp
    w, dw, _ = quintic(s)
    # ∫ quintic = t_ramp (2.5 s⁴ − 3 s⁵ + s⁶)
    return v_nom * t_ramp * (2.5 * s ** 4 - 3 * s ** 5 + s ** 6), v_nom * w, v_nom * dw / t_ramp


# --- kinematics: base + feet → (q, v, a) ---------------------------------------------------


@dataclass
class BaseState:
    """World base position p, roll-pitch-yaw φ and their first/second derivatives."""

    p: np.ndarray
    dp: np.ndarray
    ddp: np.ndarray
    rpy: np.ndarray
    drpy: np.ndarray
    ddrpy: np.ndarray


class LegIK:
    """Per-leg inverse kinematics on the foot position (damped Newton, Pinocchio)."""

    def __init__(self, robot: RobotDescription, q_seed: np.ndarray, tol: float = 1e-11, max_iter: int = 50) -> None:
        self.robot = robot
        self.model = robot.model
        self.data = robot.model.createData()
        self.q_seed = np.asarray(q_seed, float).copy()
        self.tol = tol
        self.max_iter = max_iter
        self.cols = [6 + np.asarray(leg) for leg in robot.leg_joints]
        self.qidx = [7 + np.asarray(leg) for leg in robot.leg_joints]
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        n = robot.n_feet
        self._qidx_all = np.concatenate(self.qidx)
        self._vidx_all = np.concatenate(self.cols)
        self._qidx2 = np.ascontiguousarray(self.qidx, dtype=np.int64)   # n_feet × n_leg
        self._cols2 = np.ascontiguousarray(self.cols, dtype=np.int64)
        self._J = np.zeros((n, 3, robot.model.nv))
        self._feet = np.zeros((n, 3))
        self._zeros6 = np.zeros(6)

    def _jacobians(self, q: np.ndarray) -> np.ndarray:
        """Foot Jacobians (world-aligned, linear) at q into self._J, foot positions into self._feet."""
        model, data, J, feet = self.model, self.data, self._J, self._feet
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        for i, f in enumerate(self.robot.foot_frame_ids):
            J[i] = pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3]
            feet[i] = data.oMf[f].translation
        return J

    def solve(self, base: BaseState, feet_p: np.ndarray, feet_v: np.ndarray, feet_a: np.ndarray,
              guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, v, a) that put the feet at feet_p with velocities feet_v and accelerations
        feet_a (world, n_feet × 3) for the given base trajectory point. `guess`: joint
        positions to start Newton from (default: the previous solution if close, else the seed)."""
        model, data = self.model, self.data
        R = pin.rpy.rpyToMatrix(base.rpy)
        q = self.q_seed.copy()
        q[:3] = base.p
        q[3:7] = pin.Quaternion(R).coeffs()
        if guess is not None:
            q[7:] = guess
        elif self._last is not None and np.max(np.abs(self._last[0] - feet_p)) < 0.05 \
                and np.max(np.abs(self._last[1] - q[:7])) < 0.05:
            q[7:] = self._last[2]  # warm start from the previous solution (same branch)
        feet_p = kernels.arg(feet_p)
        for _ in range(self.max_iter):
            J = self._jacobians(q)  # also places the frames at q
            # damped Newton per leg (ciml_control.kernels.leg_newton_step): (BᵀB + 1e-12 I) s = Bᵀ e, |s| ≤ 0.5
            done, worst = kernels.leg_newton_step(J, self._feet, feet_p, q, self._qidx2, self._cols2, self.tol, 1e-12, 0.5)
            if done:
                break
        else:
            raise InverseKinematicsError(
                f"leg inverse kinematics did not converge (foot error {worst:.2e} m): "
                "a foot target is out of reach")
        self._last = (feet_p.copy(), q[:7].copy(), q[7:].copy())
        # velocities: J_leg q̇_leg = ṗ − J_base v_base
        Einv_local = pin.rpy.computeRpyJacobian(base.rpy, pin.LOCAL)
        omega = Einv_local @ base.drpy
        v_lin = R.T @ base.dp
        domega = Einv_local @ base.ddrpy + pin.rpy.computeRpyJacobianTimeDerivative(base.rpy, base.drpy, pin.LOCAL) @ base.drpy
        a_lin = R.T @ base.ddp - _cross(omega, v_lin)
        nv = model.nv
        v = np.zeros(nv)
        v[:3], v[3:6] = v_lin, omega
        v[self._vidx_all] = kernels.leg_solve(J, kernels.arg(feet_v), v[:6], self._cols2).ravel()
        # accelerations: classical foot acceleration with zero joint acceleration = J_base a_base + J̇ q̇
        a = np.zeros(nv)
        a[:3], a[3:6] = a_lin, domega
        pin.forwardKinematics(model, data, q, v, a)
        pin.updateFramePlacements(model, data)
        rhs = np.array(feet_a, dtype=float)  # p̈ − drift
        for i, f in enumerate(self.robot.foot_frame_ids):
            rhs[i] -= pin.getFrameClassicalAcceleration(model, data, f, pin.LOCAL_WORLD_ALIGNED).linear
        a[self._vidx_all] = kernels.leg_solve(J, rhs, self._zeros6, self._cols2).ravel()
        return q, v, a


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


# --- references ------------------------------------------------------------------------------


class Reference:
    """A full-body reference motion: sample(t) → ReferencePoint; `period` [s] of a cycle."""

    def __init__(self, robot: RobotDescription, motion: str, q_stand: np.ndarray) -> None:
        q_stand = np.asarray(q_stand, dtype=float)
        if q_stand.shape != (robot.nq,) or not np.all(np.isfinite(q_stand)):
            raise ReferenceError_(f"q_stand must be a finite configuration of size {robot.nq}")
        self.robot = robot
        self.motion = motion
        self.spec = spec(motion)
        self.period = self.spec.period
        self.q_stand = q_stand.copy()
        self.q_stand[3:7] /= np.linalg.norm(q_stand[3:7])
        self.ik = LegIK(robot, self.q_stand)
        self._last: ReferencePoint | None = None
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, self.q_stand)
        self.feet0 = np.array([data.oMf[f].translation.copy() for f in robot.foot_frame_ids])
        self.base_p0 = self.q_stand[:3].copy()
        self.base_rpy0 = pin.rpy.matrixToRpy(pin.Quaternion(self.q_stand[3:7]).matrix())
        com = pin.centerOfMass(robot.model, data, self.q_stand)
        self.com_offset = com[:2] - self.base_p0[:2]  # CoM relative to the base, world xy

    # subclasses provide these
    def base(self, t: float) -> BaseState:
        return BaseState(self.base_p0.copy(), np.zeros(3), np.zeros(3), self.base_rpy0.copy(), np.zeros(3), np.zeros(3))

    def feet(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        n = self.robot.n_feet
        return self.feet0.copy(), np.zeros((n, 3)), np.zeros((n, 3)), np.ones(n, dtype=bool)

    def phase(self, t: float) -> float:
        return 0.0

    def sample(self, t: float) -> ReferencePoint:
        t = float(t)
        if not math.isfinite(t):
            raise ReferenceError_(f"reference time must be finite, got {t}")
        fp, fv, fa, contacts = self.feet(t)
        guess = None
        if self._last is not None and abs(t - self._last.t) <= 0.02:
            dt = t - self._last.t  # second-order predictor: Newton then needs about one step
            guess = self._last.q[7:] + dt * self._last.v[6:] + 0.5 * dt * dt * self._last.a[6:]
        q, v, a = self.ik.solve(self.base(t), fp, fv, fa, guess)
        point = ReferencePoint(t=t, q=q, v=v, a=a, contacts=contacts, phase=float(self.phase(t)), motion=self.motion)
        self._last = point
        return point


class StandReference(Reference):
    """The standing pose (the IK reproduces q_stand's feet)."""


class BaseOnlyReference(Reference):
    """Periodic cubic spline through base-pose waypoints, feet fixed (paper §V-B)."""

    def __init__(self, robot: RobotDescription, motion: str, q_stand: np.ndarray) -> None:
        super().__init__(robot, motion, q_stand)
        times = np.linspace(0.0, self.period, len(BASE_ONLY_WAYPOINTS))
        self.spline = CubicSpline(times, BASE_ONLY_WAYPOINTS, bc_type="periodic")

    def phase(self, t: float) -> float:
        return (t / self.period) % 1.0

    def base(self, t: float) -> BaseState:
        tau = t % self.period
        y, dy, ddy = self.spline(tau), self.spline(tau, 1), self.spline(tau, 2)
        w, dw, ddw = quintic(t / SETTLE_TIME)
        dw, ddw = dw / SETTLE_TIME, ddw / SETTLE_TIME ** 2
        off, doff, ddoff = w * y, dw * y + w * dy, ddw * y + 2 * dw * dy + w * ddy
        return BaseState(self.base_p0 + off[:3], doff[:3], ddoff[:3],
                         self.base_rpy0 + off[3:], doff[3:], ddoff[3:])


class GaitReference(Reference):
    """Static walk or trot with footholds from a nominal CoM progression x̄(t)."""

    def __init__(self, robot: RobotDescription, motion: str, q_stand: np.ndarray) -> None:
        super().__init__(robot, motion, q_stand)
        s = self.spec
        d = np.asarray(s.direction, float)
        self.direction = d / np.linalg.norm(d)
        self.t0 = SETTLE_TIME
        self.v_nom = s.step_length / s.period
        center = self.feet0[:, :2].mean(axis=0)
        # balanced base: CoM over the centre of the feet
        self.base_bal = self.base_p0.copy()
        self.base_bal[:2] = center - self.com_offset
        self.com0 = center
        rel = self.feet0[:, :2] - center
        along = rel @ self.direction
        perp = rel @ np.array([-self.direction[1], self.direction[0]])
        n = robot.n_feet
        if s.kind == "trot":
            # diagonal pairs: the leading-left/trailing-right pair first
            first = [i for i in range(n) if (along[i] > 0) == (perp[i] > 0)]
            self.swing_offset = np.array([0.0 if i in first else 0.5 * s.period for i in range(n)])
            self.swing_time = np.full(n, TROT_SWING)
            self.t_ramp = TROT_RAMP
        else:
            # crawl: side A (perp > 0) trailing then leading leg, then side B likewise
            side_a = sorted([i for i in range(n) if perp[i] > 0], key=lambda i: along[i])
            side_b = sorted([i for i in range(n) if perp[i] <= 0], key=lambda i: along[i])
            self.order = side_a + side_b
            offsets = [WALK_SHIFT, WALK_SHIFT + WALK_SWING, 2 * WALK_SHIFT + 2 * WALK_SWING,
                       2 * WALK_SHIFT + 3 * WALK_SWING]
            self.swing_offset = np.zeros(n)
            for k, leg in enumerate(self.order):
                self.swing_offset[leg] = offsets[k]
            self.swing_time = np.full(n, WALK_SWING)
            self.t_ramp = s.period
            self.groups = (tuple(side_a), tuple(side_b))
        self.stance_time = s.period - self.swing_time
        self._footholds: dict[tuple[int, int], tuple[float, float, float]] = {}
        self._targets: dict[tuple[int, int], tuple[float, float]] = {}

    # nominal progression of the CoM along the direction of travel
    def progression(self, t: float) -> tuple[float, float, float]:
        return ramp_distance(t - self.t0, self.v_nom, self.t_ramp)

    def phase(self, t: float) -> float:
        return ((t - self.t0) / self.period) % 1.0 if t >= self.t0 else 0.0

    # footholds: position of foot i after its k-th swing (k = -1: standing position)
    def foothold(self, leg: int, k: int) -> tuple[float, float, float]:
        key = (leg, k)
        if key not in self._footholds:
            self._footholds[key] = self._foothold(leg, k)
        return self._footholds[key]

    def _foothold(self, leg: int, k: int) -> tuple[float, float, float]:
        if k < 0:
            return tuple(self.feet0[leg])
        touchdown = self.t0 + self.swing_offset[leg] + k * self.period + self.swing_time[leg]
        x, _, _ = self.progression(touchdown + 0.5 * self.stance_time[leg])
        p = self.feet0[leg].copy()
        p[:2] += x * self.direction
        return tuple(p)

    def _swing_index(self, leg: int, t: float) -> tuple[int, float]:
        """(index k of the last swing started at or before t, time since its start)."""
        start0 = self.t0 + self.swing_offset[leg]
        if t < start0:
            return -1, 0.0
        k = int(math.floor((t - start0) / self.period))
        return k, t - start0 - k * self.period

    def feet(self, t: float):
        n = self.robot.n_feet
        p, v, a = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
        contacts = np.ones(n, dtype=bool)
        for i in range(n):
            k, since = self._swing_index(i, t)
            if k < 0:
                p[i] = self.foothold(i, -1)
                continue
            T = self.swing_time[i]
            start, end = np.array(self.foothold(i, k - 1)), np.array(self.foothold(i, k))
            if since >= T - 1e-9 or since <= 1e-9:  # touch-down/lift-off instants count as stance
                p[i] = end if since >= 0.5 * T else start
                continue
            contacts[i] = False
            s = since / T
            w, dw, ddw = quintic(s)
            b, db, ddb = bump(s)
            p[i] = start + w * (end - start)
            v[i] = dw / T * (end - start)
            a[i] = ddw / T ** 2 * (end - start)
            h = self.spec.step_height
            p[i, 2] += h * b
            v[i, 2] += h * db / T
            a[i, 2] += h * ddb / T ** 2
        return p, v, a, contacts

    def base(self, t: float) -> BaseState:
        rpy = self.base_rpy0.copy()
        zero = np.zeros(3)
        if self.spec.kind == "trot" or t < self.t0:
            w, dw, ddw = quintic(t / self.t0)
            p = self.base_p0 + w * (self.base_bal - self.base_p0)
            dp = dw / self.t0 * (self.base_bal - self.base_p0)
            ddp = ddw / self.t0 ** 2 * (self.base_bal - self.base_p0)
            if self.spec.kind == "trot":
                x, dx, ddx = self.progression(t)
                p[:2] += x * self.direction
                dp[:2] += dx * self.direction
                ddp[:2] += ddx * self.direction
            return BaseState(p, dp, ddp, rpy, zero, zero)
        # static walk: two shifts per cycle, CoM held in the support region during swings
        tc = t - self.t0
        n = int(math.floor(tc / self.period))
        tin = tc - n * self.period
        half = 0 if tin < WALK_SHIFT + 2 * WALK_SWING else 1
        shift_start = half * (WALK_SHIFT + 2 * WALK_SWING)
        target = np.array(self.walk_target(n, half))
        prev = np.array(self.walk_target(n - 1, 1) if half == 0 else self.walk_target(n, 0))
        w, dw, ddw = quintic((tin - shift_start) / WALK_SHIFT)
        p, dp, ddp = self.base_bal.copy(), np.zeros(3), np.zeros(3)
        p[:2] = prev + w * (target - prev)
        dp[:2] = dw / WALK_SHIFT * (target - prev)
        ddp[:2] = ddw / WALK_SHIFT ** 2 * (target - prev)
        return BaseState(p, dp, ddp, rpy, zero, zero)

    def walk_target(self, n: int, half: int) -> tuple[float, float]:
        """Base xy held during the two swings of side `half` in walk cycle n (cached)."""
        if (n, half) not in self._targets:
            self._targets[(n, half)] = self._walk_target(n, half)
        return self._targets[(n, half)]

    def _walk_target(self, n: int, half: int) -> tuple[float, float]:
        """Base xy held during the two swings of side `half` in walk cycle n: the CoM at the
        point nearest the nominal progression that keeps WALK_MARGIN from the edges of both
        support triangles (toward their common Chebyshev centre)."""
        if n < 0:
            return tuple(self.base_bal[:2])
        halfplanes = []
        for leg in self.groups[half]:
            # the stance feet during leg's n-th swing stand where their last swing put them
            start = self.t0 + self.swing_offset[leg] + n * self.period + 1e-9
            pts = [np.array(self.foothold(j, self._swing_index(j, start)[0]))[:2]
                   for j in range(self.robot.n_feet) if j != leg]
            halfplanes += _triangle_halfplanes(np.array(pts))
        A = np.array([h[0] for h in halfplanes])
        b = np.array([h[1] for h in halfplanes])
        res = linprog(c=[0, 0, -1], A_ub=np.hstack([A, np.ones((len(b), 1))]), b_ub=b,
                      bounds=[(None, None), (None, None), (0, None)], method="highs")
        center, radius = res.x[:2], res.x[2]
        t_mid = self.t0 + n * self.period + half * (WALK_SHIFT + 2 * WALK_SWING) + WALK_SHIFT + WALK_SWING
        x, _, _ = self.progression(t_mid)
        nominal = self.com0 + x * self.direction
        margin = min(WALK_MARGIN, 0.8 * radius)
        beta = 0.0
        d0 = b - A @ nominal
        dc = b - A @ center
        for k in range(len(b)):
            if d0[k] < margin:
                beta = max(beta, (margin - d0[k]) / (dc[k] - d0[k]))
        com = nominal + min(beta, 1.0) * (center - nominal)
        return tuple(com - self.com_offset)


def _triangle_halfplanes(pts: np.ndarray) -> list[tuple[np.ndarray, float]]:
    """Half-planes nᵀx ≤ c (n unit outward normal) of the triangle through 3 points."""
    centroid = pts.mean(axis=0)
    out = []
    for k in range(3):
        a, b = pts[k], pts[(k + 1) % 3]
        e = b - a
        nrm = np.array([e[1], -e[0]]) / np.linalg.norm(e)
        if nrm @ (centroid - a) > 0:
            nrm = -nrm
        out.append((nrm, float(nrm @ a)))
    return out


def standing_configuration(robot: RobotDescription, foot_height: float = 0.0) -> np.ndarray:
    """The robot's standing pose (robot.standing_joints, level base at the origin) with the
    lowest foot frame `foot_height` [m] above the ground (the foot radius of a sphere foot)."""
    q = pin.neutral(robot.model)
    q[7:] = robot.standing_joints
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    q[2] = foot_height - min(data.oMf[f].translation[2] for f in robot.foot_frame_ids)
    return q


def make_reference(robot: RobotDescription, motion: str, q_stand: np.ndarray) -> Reference:
    """The reference of `motion` (one of MOTIONS) starting from the standing pose q_stand.

    Raises UnknownMotionError (a CimlError) naming the valid motions.
    """
    kind = spec(motion).kind
    if kind == "stand":
        return StandReference(robot, motion, q_stand)
    if kind == "base_only":
        return BaseOnlyReference(robot, motion, q_stand)
    return GaitReference(robot, motion, q_stand)
