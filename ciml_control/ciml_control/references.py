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
  base moves at constant velocity after a C² velocity ramp, plus a small lateral sway that
  keeps the zero-moment point on the line of the two stance feet (trot_sway: with two
  feet on a line no joint torque produces a moment about it, so a straight-line base path
  asks the contacts for a moment they cannot give, up to m·g times the CoM's distance from
  the line — the sway lets gravity and inertia cancel it instead; a few millimetres).
Every gait starts with a settle phase (all feet down) in which the base moves from the
standing pose to the pose that puts the CoM over the centre of the feet.

Footholds are placed under the hips at the middle of the following stance (relative to
a nominal progression x̄(t) of the CoM), so feet travel symmetrically about their
standing position. Swing feet follow a quintic (minimum-jerk) horizontal path and a
vertical bump h·64 s³(1−s)³: zero velocity and acceleration at lift-off and touch-down,
so qᵈ is C² across contact changes.

Nothing here assumes HyQ: legs, feet and the standing pose come from the robot
description and the q_stand argument. The motions' lengths (step length and height, the walk's
CoM margin, base_only's translations) are HyQ's, the robot they were sized for, times
`leg_scale(robot)` (leg length relative to HyQ's); their periods are kept. Measured on go1
(go1_gap, 40 s headless, seed 1): trot_35 with HyQ's lengths 6.2 Nm RMS feedback effort, 3.3°
attitude error, and trot_45 fell; scaled (× 0.61) 3.3 Nm, 0.5°, and trot_45 trots (3.6 Nm,
0.8°); scaling the periods too (Froude, × √0.61) tracked worse (4.1 Nm, 4.8 Nm).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np
import pinocchio as pin

from ciml_learning.core.dynamics import quaternion_xyzw
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription

from . import native
from .compiled.leg_ik import leg_ik, leg_rates
from .compiled.linalg import arg


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
WALK_MARGIN = 0.06      # [m] distance of the CoM target from the support triangles' edges (HyQ; × leg_scale)
TROT_PERIOD = 0.6
TROT_SWING = 0.27       # [s] per diagonal pair; 0.03 s four-foot support at each switch
TROT_RAMP = 2.0         # [s] C² velocity ramp
SWITCH_TOLERANCE = 1e-6
"""[s] A sample this close to a contact switch is at the switch: a time in seconds from ns stamps
carries rounding, and a clock that adds its step drifts (MuJoCo's time += dt: 21 ns in 20 min);
a control period is thousands of times longer."""
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
# one per second, periodic (the last equals the first); translations for HyQ (× leg_scale)
BASE_ONLY_WAYPOINTS = np.array([
    [0.00, 0.00, 0.00, 0.00, 0.00, 0.00],
    [0.05, 0.03, -0.04, 0.06, 0.00, 0.08],
    [-0.02, -0.05, 0.02, -0.06, 0.07, 0.00],
    [-0.05, 0.02, -0.05, 0.00, -0.07, -0.08],
    [0.02, -0.03, 0.01, 0.05, 0.04, 0.05],
    [0.00, 0.00, 0.00, 0.00, 0.00, 0.00],
])


REFERENCE_LEG_LENGTH = 0.696
"""[m] HyQ's leg length (leg_length), the robot the motions' lengths were sized for."""


def leg_length(robot: RobotDescription) -> float:
    """Mean distance from each leg's hip flexion axis (its second joint) to its foot with the legs
    straight (the neutral configuration) [m]: HyQ 0.696, go1 0.426, solo12 0.323."""
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, pin.neutral(robot.model))
    return float(np.mean([np.linalg.norm(data.oMf[foot].translation - data.oMi[leg[1] + 2].translation)
                          for leg, foot in zip(robot.leg_joints, robot.foot_frame_ids)]))


def leg_scale(robot: RobotDescription) -> float:
    """Length scale of the motions for `robot`: leg_length / REFERENCE_LEG_LENGTH, two significant
    digits (HyQ exactly 1, go1 0.61, solo12 0.46)."""
    return float(f"{leg_length(robot) / REFERENCE_LEG_LENGTH:.2g}")


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
    """Per-leg inverse kinematics on the foot position (damped Newton, Pinocchio's
    kinematics in the controller's C++ core: compiled.leg_ik.leg_ik)."""

    def __init__(self, robot: RobotDescription, q_seed: np.ndarray, tol: float = 1e-11, max_iter: int = 50) -> None:
        self.robot = robot
        self.q_seed = np.asarray(q_seed, float).copy()
        self.tol = tol
        self.max_iter = max_iter
        self.cols = [6 + np.asarray(leg) for leg in robot.leg_joints]
        self.qidx = [7 + np.asarray(leg) for leg in robot.leg_joints]
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        n = robot.n_feet
        self._qidx2 = np.ascontiguousarray(self.qidx, dtype=np.int64)   # n_feet × n_leg
        self._cols2 = np.ascontiguousarray(self.cols, dtype=np.int64)
        self._J = np.zeros((n, 3, robot.model.nv))
        self._feet = np.zeros((n, 3))
        self._functions = native.function_table()  # the robot's model in the C++ core (ciml_control.native)
        self._core = native.Dynamics(robot)

    def solve(self, base: BaseState, feet_p: np.ndarray, feet_v: np.ndarray, feet_a: np.ndarray,
              guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, v, a) that put the feet at feet_p with velocities feet_v and accelerations
        feet_a (world, n_feet × 3) for the given base trajectory point. `guess`: joint
        positions to start Newton from (default: the previous solution if close, else the seed)."""
        R = pin.rpy.rpyToMatrix(base.rpy)
        q = self.q_seed.copy()
        q[:3] = base.p
        q[3:7] = quaternion_xyzw(R)
        if guess is not None:
            q[7:] = guess
        elif self._last is not None and np.max(np.abs(self._last[0] - feet_p)) < 0.05 \
                and np.max(np.abs(self._last[1] - q[:7])) < 0.05:
            q[7:] = self._last[2]  # warm start from the previous solution (same branch)
        feet_p = arg(feet_p)
        # damped Newton per leg (compiled.leg_ik.leg_ik, leg_newton_step): (BᵀB + 1e-12 I) s = Bᵀ e, |s| ≤ 0.5
        J = self._J
        done, worst = leg_ik(self._functions, self._core.handle, q, feet_p, self._qidx2, self._cols2, self.tol,
                                     self.max_iter, J, self._feet)
        if not done:
            raise InverseKinematicsError(
                f"leg inverse kinematics did not converge (foot error {worst:.2e} m): "
                "a foot target is out of reach")
        self._last = (feet_p.copy(), q[:7].copy(), q[7:].copy())
        # velocities and accelerations of the legs that carry the feet along (compiled.leg_ik.leg_rates)
        v, a = leg_rates(self._functions, self._core.handle, q, J, R,
                                 pin.rpy.computeRpyJacobian(base.rpy, pin.LOCAL),
                                 pin.rpy.computeRpyJacobianTimeDerivative(base.rpy, base.drpy, pin.LOCAL),
                                 *(arg(x) for x in (base.dp, base.ddp, base.drpy, base.ddrpy, feet_v, feet_a)),
                                 self._cols2)
        return q, v, a


def _hermite(s: float, d: float, y0: float, v0: float, y1: float, v1: float) -> tuple[float, float, float]:
    """Cubic Hermite from (y0, v0) to (y1, v1) over [0, d], at s: value and two derivatives."""
    x = s / d
    h00, h10, h01, h11 = 2 * x ** 3 - 3 * x ** 2 + 1, x ** 3 - 2 * x ** 2 + x, -2 * x ** 3 + 3 * x ** 2, x ** 3 - x ** 2
    d00, d10, d01, d11 = 6 * x ** 2 - 6 * x, 3 * x ** 2 - 4 * x + 1, -6 * x ** 2 + 6 * x, 3 * x ** 2 - 2 * x
    e00, e10, e01, e11 = 12 * x - 6, 6 * x - 4, -12 * x + 6, 6 * x - 2
    y = h00 * y0 + h10 * d * v0 + h01 * y1 + h11 * d * v1
    dy = (d00 * y0 + d10 * d * v0 + d01 * y1 + d11 * d * v1) / d
    ddy = (e00 * y0 + e10 * d * v0 + e01 * y1 + e11 * d * v1) / d ** 2
    return y, dy, ddy


# --- references ------------------------------------------------------------------------------


class Reference:
    """A full-body reference motion: sample(t) → ReferencePoint; `period` [s] of a cycle."""

    def __init__(self, robot: RobotDescription, motion: str, q_stand: np.ndarray) -> None:
        q_stand = np.asarray(q_stand, dtype=float)
        if q_stand.shape != (robot.nq,) or not np.all(np.isfinite(q_stand)):
            raise ReferenceError_(f"q_stand must be a finite configuration of size {robot.nq}")
        self.robot = robot
        self.motion = motion
        self.scale = leg_scale(robot)
        s = spec(motion)
        self.spec = replace(s, step_length=s.step_length * self.scale, step_height=s.step_height * self.scale)
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
        self.com_height = float(com[2] - self.feet0[:, 2].mean())  # above the feet [m]

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
        # scipy here, not at the top: every node imports this module, and only this motion needs it
        # (scipy.interpolate costs a node ~0.3 s of CPU at start-up)
        from scipy.interpolate import CubicSpline

        times = np.linspace(0.0, self.period, len(BASE_ONLY_WAYPOINTS))
        waypoints = BASE_ONLY_WAYPOINTS * np.r_[np.full(3, self.scale), np.ones(3)]
        self.spline = CubicSpline(times, waypoints, bc_type="periodic")

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


RECENT_ENTRIES = 256
"""Entries kept in each of a gait's caches (footholds, sway, walk targets: one per step or
interval): a live reference runs for hours and time moves forward, so only recent steps are
asked for again; unbounded, the caches grew the reference's memory by ~1.4 MB per minute."""


def _recent(cache: dict, key, compute: Callable[[], Any]) -> Any:
    """cache[key], computed once; the oldest entry is dropped past RECENT_ENTRIES."""
    if key not in cache:
        cache[key] = compute()
        if len(cache) > RECENT_ENTRIES:
            del cache[next(iter(cache))]  # dicts keep insertion order
    return cache[key]


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
        self._balance_shift = self.base_bal - self.base_p0
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
            # imported with the motion, not at the top (only the walk needs it) and not at its first
            # target, which the reference generator computes inside its 250 Hz timer
            from scipy.optimize import linprog

            self._linprog = linprog
        self.stance_time = s.period - self.swing_time
        self._footholds: dict[tuple[int, int], tuple[float, float, float]] = {}
        self._targets: dict[tuple[int, int], tuple[float, float]] = {}
        self._sway: dict[int, tuple[np.ndarray, float, float, float]] = {}
        self._sway_b: dict[int, np.ndarray] = {}  # particular cubic per interval
        self._sway_solver: tuple[LegIK, pin.Data] | None = None
        self.lateral = np.array([-self.direction[1], self.direction[0]])

    # nominal progression of the CoM along the direction of travel
    def progression(self, t: float) -> tuple[float, float, float]:
        return ramp_distance(t - self.t0, self.v_nom, self.t_ramp)

    def phase(self, t: float) -> float:
        return ((t - self.t0) / self.period) % 1.0 if t >= self.t0 else 0.0

    # footholds: position of foot i after its k-th swing (k = -1: standing position)
    def foothold(self, leg: int, k: int) -> tuple[float, float, float]:
        return _recent(self._footholds, (leg, k), lambda: self._foothold(leg, k))

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
            T = float(self.swing_time[i])
            start, end = self.foothold(i, k - 1), self.foothold(i, k)
            # touch-down/lift-off instants count as stance
            if since >= T - SWITCH_TOLERANCE or since <= SWITCH_TOLERANCE:
                p[i] = end if since >= 0.5 * T else start
                continue
            contacts[i] = False
            s = since / T
            w, dw, ddw = quintic(s)
            b, db, ddb = bump(s)
            h = self.spec.step_height
            # straight line start → end (quintic) plus the step height's bump; scalar arithmetic
            # (a handful of 3-vectors: numpy's per-call cost would dominate)
            fv, fa = dw / T, ddw / T ** 2
            for c in range(3):
                d = end[c] - start[c]
                p[i, c], v[i, c], a[i, c] = start[c] + w * d, fv * d, fa * d
            p[i, 2] += h * b
            v[i, 2] += h * db / T
            a[i, 2] += h * ddb / T ** 2
        return p, v, a, contacts

    def base(self, t: float, sway: bool = True) -> BaseState:
        rpy = self.base_rpy0.copy()
        zero = np.zeros(3)
        if self.spec.kind == "trot" or t < self.t0:
            # balance shift (quintic), plus the trot's progression and sway in the plane; scalar
            # arithmetic on 3-vectors (numpy's per-call cost would dominate)
            w, dw, ddw = quintic(t / self.t0)
            fv, fa = dw / self.t0, ddw / self.t0 ** 2
            p0, d = self.base_p0, self._balance_shift
            p = [p0[c] + w * d[c] for c in range(3)]
            dp, ddp = [fv * d[c] for c in range(3)], [fa * d[c] for c in range(3)]
            if self.spec.kind == "trot":
                planar = [(self.progression(t), self.direction)]
                if sway:
                    planar.append((self.trot_sway(t), self.lateral))
                for (x, dx, ddx), e in planar:
                    for c in range(2):
                        p[c] += x * e[c]
                        dp[c] += dx * e[c]
                        ddp[c] += ddx * e[c]
            return BaseState(np.array(p), np.array(dp), np.array(ddp), rpy, zero, zero)
        # static walk: two shifts per cycle, CoM held in the support region during swings
        tc = t - self.t0
        n = int(math.floor(tc / self.period))
        tin = tc - n * self.period
        half = 0 if tin < WALK_SHIFT + 2 * WALK_SWING else 1
        shift_start = half * (WALK_SHIFT + 2 * WALK_SWING)
        target = np.array(self.walk_target(n, half))
        prev = np.array(self.walk_target(n - 1, 1) if half == 0 else self.walk_target(n, 0))
        w, dw, ddw = quintic((tin - shift_start) / WALK_SHIFT)
        pos, vel, acc = self.base_bal.copy(), np.zeros(3), np.zeros(3)
        pos[:2] = prev + w * (target - prev)
        vel[:2] = dw / WALK_SHIFT * (target - prev)
        acc[:2] = ddw / WALK_SHIFT ** 2 * (target - prev)
        return BaseState(pos, vel, acc, rpy, zero, zero)

    def trot_sway(self, t: float) -> tuple[float, float, float]:
        """Lateral base offset y (along `lateral`) and its derivatives for the trot.

        While one diagonal pair stands alone (the other swings, T = TROT_SWING), the contact
        forces of the two feet have no moment about the line through them, so the whole body's
        moment about that line, M = u·[(c − p)×(m c̈ − m g) + L̇_G] (c the CoM, L_G the
        centroidal angular momentum, Pinocchio), must vanish. A lateral shift y of the CoM
        changes M by K (y − ÿ/ω²) (K = m g u·(lateral × e_z), ω² = g/h, h the CoM height: the
        linear inverted pendulum), so y − ÿ/ω² = L(τ) = −M₀(τ)/K with M₀ the moment of the
        straight path (sampled, cubic in τ over the interval). Of its solutions (a particular
        cubic plus A cosh ωτ + B sinh ωτ) the sway takes the periodic orbit of the two pairs:
        position and velocity continuous through the four-foot support between intervals,
        which a cubic Hermite bridges. While the gait speeds up it is not periodic: the sway
        fades in over the cycle after the velocity ramp (quintic factor)."""
        fade, dfade, ddfade = quintic((t - self.t0 - self.t_ramp) / self.period)
        if fade <= 0.0:
            return 0.0, 0.0, 0.0
        P = self.period
        tc = t - self.t0
        half = 0.5 * P
        # interval k: [k·P/2, k·P/2 + TROT_SWING) after t0. ÿ jumps at each switch (the support line
        # changes), so a sample at a switch instant takes the motion that follows it (the 4 ms its
        # command holds), whichever way the rounding of t falls
        k = int(math.floor((tc + SWITCH_TOLERANCE) / half))
        tin = tc - k * half
        if tin < TROT_SWING - SWITCH_TOLERANCE:
            y, dy, ddy = self._sway_interval(k, tin - 0.5 * TROT_SWING)
        else:  # four-foot support: cubic Hermite from the end of interval k to the start of k + 1
            y0, v0, _ = self._sway_interval(k, 0.5 * TROT_SWING)
            y1, v1, _ = self._sway_interval(k + 1, -0.5 * TROT_SWING)
            y, dy, ddy = _hermite(tin - TROT_SWING, half - TROT_SWING, y0, v0, y1, v1)
        dfade, ddfade = dfade / P, ddfade / P ** 2
        return fade * y, fade * dy + dfade * y, fade * ddy + 2 * dfade * dy + ddfade * y

    def _sway_interval(self, k: int, tau: float) -> tuple[float, float, float]:
        """(y, ẏ, ÿ) at τ from the middle of two-foot interval k."""
        b, A, B, w = _recent(self._sway, k, lambda: self._sway_coefficients(k))
        sh, ch = math.sinh(w * tau), math.cosh(w * tau)
        y = b[0] + tau * (b[1] + tau * (b[2] + tau * b[3])) + A * ch + B * sh
        dy = b[1] + tau * (2 * b[2] + 3 * tau * b[3]) + w * (A * sh + B * ch)
        ddy = 2 * b[2] + 6 * tau * b[3] + w * w * (A * ch + B * sh)
        return y, dy, ddy

    def _sway_particular(self, k: int) -> np.ndarray:
        """Cubic b (y_p − y_p''/ω² = L, L = −M₀/K sampled on two-foot interval k; trot_sway)."""
        T = TROT_SWING
        w2 = 9.81 / self.com_height
        t_mid = self.t0 + 0.5 * k * self.period + 0.5 * T
        swinging = 0.0 if k % 2 == 0 else 0.5 * self.period
        stance = [i for i in range(self.robot.n_feet) if abs(self.swing_offset[i] - swinging) > 1e-9]
        feet = np.array([self.foothold(i, self._swing_index(i, t_mid)[0]) for i in stance])
        u = (feet[1] - feet[0]) / np.linalg.norm(feet[1] - feet[0])
        model = self.robot.model
        if self._sway_solver is None:  # its own IK and data: the reference's warm starts stay untouched
            self._sway_solver = (LegIK(self.robot, self.q_stand), model.createData())
        ik, data = self._sway_solver
        mg = self.robot.total_mass * 9.81
        K = mg * float(u @ np.cross([self.lateral[0], self.lateral[1], 0.0], [0.0, 0.0, 1.0]))
        if abs(K) < 0.2 * mg:  # the line runs along `lateral`: no lateral sway helps
            return np.zeros(4)
        taus = np.linspace(-0.5 * T, 0.5 * T, 7)
        L = np.zeros(len(taus))
        for n, tau in enumerate(taus):
            fp, fv, fa, _ = self.feet(t_mid + tau)
            q, v, a = ik.solve(self.base(t_mid + tau, sway=False), fp, fv, fa)
            pin.computeCentroidalMomentumTimeVariation(model, data, q, v, a)  # also the CoM, data.com[0]
            force = data.dhg.linear + np.array([0.0, 0.0, mg])
            L[n] = -float(u @ (np.cross(data.com[0] - feet[0], force) + data.dhg.angular)) / K
        a3, a2, a1, a0 = np.polyfit(taus, L, 3)
        return np.array([a0 + 2 * a2 / w2, a1 + 6 * a3 / w2, a2, a3])

    def _sway_coefficients(self, k: int) -> tuple[np.ndarray, float, float, float]:
        """(b, A, B, ω) of interval k on the periodic orbit it forms with its partner interval
        (k ± 1, the other pair): y, ẏ continuous through the four-foot support (d) both ways,
        y_j(−h) = y_k(h) + d ẏ_k(h), ẏ_j(−h) = ẏ_k(h), and the same from j to k."""
        j = k + 1 if k % 2 == 0 else k - 1
        w = math.sqrt(9.81 / self.com_height)
        h = 0.5 * TROT_SWING
        d = 0.5 * self.period - TROT_SWING
        b = {i: _recent(self._sway_b, i, partial(self._sway_particular, i)) for i in (k, j)}

        def poly(c: np.ndarray, tau: float) -> tuple[float, float]:
            return (c[0] + tau * (c[1] + tau * (c[2] + tau * c[3])), c[1] + tau * (2 * c[2] + 3 * tau * c[3]))

        S, C = math.sinh(w * h), math.cosh(w * h)
        hom = {h: np.array([[C, S], [w * S, w * C]]), -h: np.array([[C, -S], [-w * S, w * C]])}  # rows y, ẏ
        Dt = np.array([[1.0, d], [0.0, 1.0]])  # (y, ẏ) carried through the four-foot support
        # unknowns [A_k, B_k, A_j, B_j]: start(next) − Dt·end(this) = 0, both ways
        M, r = np.zeros((4, 4)), np.zeros(4)
        for row, (this, nxt) in enumerate(((k, j), (j, k))):
            ci, cn = (0, 2) if this == k else (2, 0)
            M[2 * row:2 * row + 2, cn:cn + 2] = hom[-h]
            M[2 * row:2 * row + 2, ci:ci + 2] = -Dt @ hom[h]
            r[2 * row:2 * row + 2] = Dt @ np.array(poly(b[this], h)) - np.array(poly(b[nxt], -h))
        A_k, B_k, _, _ = np.linalg.solve(M, r)
        return b[k], float(A_k), float(B_k), w

    def walk_target(self, n: int, half: int) -> tuple[float, float]:
        """Base xy held during the two swings of side `half` in walk cycle n (cached)."""
        return _recent(self._targets, (n, half), lambda: self._walk_target(n, half))

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
        res = self._linprog(c=[0, 0, -1], A_ub=np.hstack([A, np.ones((len(b), 1))]), b_ub=b,
                      bounds=[(None, None), (None, None), (0, None)], method="highs")
        center, radius = res.x[:2], res.x[2]
        t_mid = self.t0 + n * self.period + half * (WALK_SHIFT + 2 * WALK_SWING) + WALK_SHIFT + WALK_SWING
        x, _, _ = self.progression(t_mid)
        nominal = self.com0 + x * self.direction
        margin = min(WALK_MARGIN * self.scale, 0.8 * radius)
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
