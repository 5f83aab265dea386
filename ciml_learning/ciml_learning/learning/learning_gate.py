"""When the online learner may learn: only while the robot is up, tracks its reference, and
the measured error is physical (docs/LIVE_GRAPH.md, "Safety").

Online learning in closed loop feeds on itself: a robot that falls produces huge "model
errors" (the ground, not the model, holds the trunk), the learned error reaches the
controller, and the controller makes the fall worse. The gate stops that loop at its
source. A (state, error) pair is learned only if, at its stamp,

- the robot is up: base height ≥ `min_height_ratio` × the robot's standing height
  (physical_bounds.standing_height) and the base tilt (angle between the base's z axis and
  the vertical) ≤ `max_tilt`;
- it tracks its reference (the /reference sample with the nearest stamp, within
  `max_reference_age`): base position error ≤ `max_position_error`, attitude error (angle of
  R_refᵀR) ≤ `max_attitude_error`, RMS joint error ≤ `max_joint_error`. With no reference
  at all (learning from a replayed log) the tracking check is skipped unless
  `require_reference`; once references have been seen, a missing one pauses learning;
- the target is physical: every Φ̃' and Γ entry within physical_bounds (m·g, m·g·leg span,
  torque limits), times `bound_scale` (1 by default).

Any failed check *pauses* learning, with the reason; learning resumes once every check has
passed for `resume_after` seconds of stamps (the robot has recovered, not just crossed the
threshold once). The defaults are generous against the measured tracking of the default
gap scenario (trot_35, headless, nominal model: position error p99 12 mm, attitude
0.09 rad, RMS joint error 0.05 rad).
"""
from __future__ import annotations

import math
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np

from ciml_learning.core.physical_bounds import physical_bounds
from ciml_learning.core.robot import RobotDescription

FALL = "paused_fall"
TRACKING = "paused_tracking_error"
TARGET = "paused_target_beyond_bounds"
NO_REFERENCE = "paused_no_reference"
HOLD = "paused_recovering"
"""Pause reasons (also the counters of rejected pairs)."""


@dataclass
class GateConfig:
    min_height_ratio: float = 0.5      # of the standing height
    max_tilt: float = 0.5              # [rad] (~29°)
    max_position_error: float = 0.15   # [m]
    max_attitude_error: float = 0.35   # [rad]
    max_joint_error: float = 0.3       # [rad] RMS over joints
    max_reference_age: float = 0.02    # [s] between the state's and the nearest reference's stamp
    resume_after: float = 1.0          # [s] of passing checks before learning resumes
    require_reference: bool = False
    bound_scale: float = 1.0           # × the physical bounds on targets (> 1: a robot pushed beyond its weight)


def tilt_angle(quat_xyzw: np.ndarray) -> float:
    """Angle between the base's z axis and the world's vertical [rad] (quaternion x, y, z, w)."""
    x, y, z, w = (float(c) for c in quat_xyzw)
    n = x * x + y * y + z * z + w * w
    # z component of R e_z = 1 − 2(x² + y²) for a unit quaternion
    cz = 1.0 - 2.0 * (x * x + y * y) / n
    return math.acos(max(-1.0, min(1.0, cz)))


def attitude_error(quat_xyzw: np.ndarray, ref_xyzw: np.ndarray) -> float:
    """Angle of R_refᵀR [rad]."""
    a = np.asarray(quat_xyzw, float) / np.linalg.norm(quat_xyzw)
    b = np.asarray(ref_xyzw, float) / np.linalg.norm(ref_xyzw)
    return 2.0 * math.acos(min(1.0, abs(float(a @ b))))


class LearningGate:
    """The checks of the module docstring with pause / resume; pure (no ROS).

    add_reference(stamp_ns, q_ref) keeps the recent references (Pinocchio q: position,
    quaternion x y z w, joints); check(stamp_ns, q, rbd_error, actuation_error) returns None
    if the pair may be learned, else the pause reason (counted in `counts`). `paused` and
    `reason` (one line, with the measured value) describe the current state.
    """

    def __init__(self, robot: RobotDescription, config: GateConfig | None = None, max_references: int = 500) -> None:
        self.robot = robot
        self.config = config or GateConfig()
        self.bounds = physical_bounds(robot)
        self.min_height = self.config.min_height_ratio * self.bounds.standing_height
        self._references: deque[tuple[int, np.ndarray]] = deque(maxlen=max_references)
        self.references_seen = 0
        self.paused = False
        self.reason = ""
        self.key = ""  # the current pause's reason (one of the paused_* keys)
        self._last_bad = 0  # stamp [ns] of the last refused sample (read while paused)
        self.counts: Counter[str] = Counter()

    def add_reference(self, stamp_ns: int, q_ref: np.ndarray) -> None:
        stamp_ns = int(stamp_ns)
        if self._references and stamp_ns <= self._references[-1][0]:
            # a restarted reference stream (or out of order): start over, never mix two streams
            self._references.clear()
        self._references.append((stamp_ns, np.asarray(q_ref, dtype=float)))
        self.references_seen += 1

    @property
    def newest_reference(self) -> int | None:
        """Stamp [ns] of the newest reference kept (None before the first)."""
        return self._references[-1][0] if self._references else None

    def reference_at(self, stamp_ns: int) -> np.ndarray | None:
        """q of the reference with the nearest stamp within max_reference_age, else None."""
        if not self._references:
            return None
        stamps = [s for s, _ in self._references]
        i = int(np.searchsorted(stamps, stamp_ns))
        best = min((j for j in (i - 1, i) if 0 <= j < len(stamps)), key=lambda j: abs(stamps[j] - stamp_ns))
        if abs(stamps[best] - stamp_ns) > self.config.max_reference_age * 1e9:
            return None
        return self._references[best][1]

    def _problem(self, stamp_ns: int, q: np.ndarray, rbd_error: np.ndarray,
                 actuation_error: np.ndarray) -> tuple[str, str] | None:
        c = self.config
        z, tilt = float(q[2]), tilt_angle(q[3:7])
        if not z >= self.min_height:
            return FALL, f"fall: base height {z:.3f} m below {self.min_height:.3f} m"
        if not tilt <= c.max_tilt:
            return FALL, f"fall: base tilted {math.degrees(tilt):.0f}° (limit {math.degrees(c.max_tilt):.0f}°)"
        q_ref = self.reference_at(stamp_ns)
        if q_ref is None:
            if c.require_reference or self.references_seen:
                return NO_REFERENCE, "no /reference within " \
                                     f"{1e3 * c.max_reference_age:.0f} ms of the state's stamp"
        else:
            pos = float(np.linalg.norm(q[:3] - q_ref[:3]))
            if not pos <= c.max_position_error:
                return TRACKING, f"tracking error: base position {pos:.3f} m (limit {c.max_position_error:g} m)"
            att = attitude_error(q[3:7], q_ref[3:7])
            if not att <= c.max_attitude_error:
                return TRACKING, f"tracking error: attitude {att:.3f} rad (limit {c.max_attitude_error:g} rad)"
            joint = float(np.sqrt(np.mean((q[7:] - q_ref[7:]) ** 2)))
            if not joint <= c.max_joint_error:
                return TRACKING, f"tracking error: RMS joint {joint:.3f} rad (limit {c.max_joint_error:g} rad)"
        bad = (self.bounds.rbd_violation(rbd_error, c.bound_scale)
               or self.bounds.actuation_violation(actuation_error, c.bound_scale))
        if bad:
            return TARGET, f"target beyond physical bounds: {bad}"
        return None

    def check(self, stamp_ns: int, q: np.ndarray, rbd_error: np.ndarray, actuation_error: np.ndarray) -> str | None:
        """None: learn this pair; else the pause reason (counted)."""
        stamp_ns = int(stamp_ns)
        problem = self._problem(stamp_ns, np.asarray(q, float), rbd_error, actuation_error)
        if problem is not None:
            self.key, self.reason = problem
            self.paused = True
            self._last_bad = stamp_ns
            self.counts[self.key] += 1
            return self.key
        if self.paused:
            if stamp_ns < self._last_bad:  # the stamps restarted: the recovery time starts again
                self._last_bad = stamp_ns
            if stamp_ns - self._last_bad < self.config.resume_after * 1e9:
                self.counts[HOLD] += 1
                return HOLD
            self.paused, self.reason = False, ""
            self.counts["resumed"] += 1
        return None
