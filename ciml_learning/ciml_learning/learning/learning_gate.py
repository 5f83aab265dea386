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
  `max_reference_age`: pairing.ReferenceHistory, kept by error_extractor, which sends it with the
  sample so that the learner reads no control-path topic): base position error
  ≤ `max_position_error`, attitude error (angle of R_refᵀR) ≤ `max_attitude_error`, RMS joint
  error ≤ `max_joint_error`. With no reference at all (learning from a replayed log) the
  tracking check is skipped unless `require_reference`; once references have been seen, a
  missing one pauses learning;
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
from typing import Any

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


MAX_REFERENCE_AGE = 0.02
"""[s] default largest stamp distance between a state and the reference of its instant."""


class AwaitReference:
    """Learning samples wait here (error_extractor), in stamp order, until the /reference stream
    has passed their stamp.

    The tracking check needs the reference of the sample's own instant, but the streams arrive
    independently: a state that comes before its reference and is sent without one pauses
    learning for `resume_after` on a reference that is merely late. ready() releases, in order,
    the samples whose stamp the newest reference has reached (within `tolerance_ns`: the
    max_reference_age), all samples while no reference was ever heard (a replayed log), and
    samples that waited more than `max_wait_ns` of stamps behind the newest sample (the reference
    stream is late or dead: the learner's gate then pauses on "no reference", as it must)."""

    def __init__(self, tolerance_ns: int, max_wait_ns: int) -> None:
        self.tolerance_ns = int(tolerance_ns)
        self.max_wait_ns = int(max_wait_ns)
        self.pending: deque[tuple[int, Any]] = deque()

    def push(self, stamp_ns: int, value: Any) -> None:
        self.pending.append((int(stamp_ns), value))

    def ready(self, newest_reference: int | None) -> list[tuple[int, Any]]:
        out = []
        newest = self.pending[-1][0] if self.pending else 0
        while self.pending:
            stamp = self.pending[0][0]
            if (newest_reference is None or newest_reference >= stamp - self.tolerance_ns
                    or newest - stamp > self.max_wait_ns):
                out.append(self.pending.popleft())
            else:
                break
        return out


class LearningGate:
    """The checks of the module docstring with pause / resume; pure (no ROS).

    check(stamp_ns, q, rbd_error, actuation_error, q_ref, references_heard) returns None if the
    pair may be learned, else the pause reason (counted in `counts`); q_ref is the Pinocchio q
    (position, quaternion x y z w, joints) of the reference of the pair's instant, or None, and
    references_heard says whether a reference stream exists at all. `paused` and `reason` (one
    line, with the measured value) describe the current state.
    """

    def __init__(self, robot: RobotDescription, config: GateConfig | None = None) -> None:
        self.robot = robot
        self.config = config or GateConfig()
        self.bounds = physical_bounds(robot)
        self.min_height = self.config.min_height_ratio * self.bounds.standing_height
        self.paused = False
        self.reason = ""
        self.key = ""  # the current pause's reason (one of the paused_* keys)
        self._last_bad = 0  # stamp [ns] of the last refused sample (read while paused)
        self.counts: Counter[str] = Counter()

    def _problem(self, q: np.ndarray, rbd_error: np.ndarray, actuation_error: np.ndarray,
                 q_ref: np.ndarray | None, references_heard: bool) -> tuple[str, str] | None:
        c = self.config
        z, tilt = float(q[2]), tilt_angle(q[3:7])
        if not z >= self.min_height:
            return FALL, f"fall: base height {z:.3f} m below {self.min_height:.3f} m"
        if not tilt <= c.max_tilt:
            return FALL, f"fall: base tilted {math.degrees(tilt):.0f}° (limit {math.degrees(c.max_tilt):.0f}°)"
        if q_ref is None:
            if c.require_reference or references_heard:
                return NO_REFERENCE, "no /reference at the state's stamp (error_extractor's max_reference_age)"
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

    def check(self, stamp_ns: int, q: np.ndarray, rbd_error: np.ndarray, actuation_error: np.ndarray,
              q_ref: np.ndarray | None = None, references_heard: bool = False) -> str | None:
        """None: learn this pair; else the pause reason (counted)."""
        stamp_ns = int(stamp_ns)
        problem = self._problem(np.asarray(q, float), rbd_error, actuation_error, q_ref, references_heard)
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
