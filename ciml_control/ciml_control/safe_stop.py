"""What the controller tracks when its reference is late: feet down, then stand, and
resume only a reference that is still where the robot is.

Measured headless (HyQ, trot_35, nominal plant; ciml_control/test/test_safe_stop.py): with
the last pose held, a reference that stalls for 0.35 s does not drop the robot while it is
stale, but its return does: the motion went on for 0.35 s (12 cm at 0.35 m/s) while the
robot stood, the base task chases that jump, and the robot falls within ~1.5 s. A stall of
0.2 s (7 cm) is tracked again without a fall. Hence:
- stale: the base and the stance feet hold the last reference; each swing foot goes straight
  down to the ground (leg inverse kinematics, minimum-jerk over `landing_time`), then the
  robot stands on all feet. Moving the swing legs to the standing posture instead put a
  foot that touched down early where the posture's foot is not, and rolled the base;
- fresh again: resumed only if the reference's base is within `resume_tolerance` of the
  pose the robot stopped at; otherwise the robot keeps standing (the motion must be
  restarted), which the node reports.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from ciml_learning.robot import RobotDescription

from .references import BaseState, LegIK, ReferencePoint, quintic

LANDING_TIME = 0.2       # [s] swing feet to the ground: about half a trot cycle, a swing's own length
RESUME_TOLERANCE = 0.02  # [m] base position jump a resumed reference may have (headless: 2.8 cm dropped HyQ)

LIVE, LANDING, STANDING = "live", "landing", "standing"


class SafeStop:
    """The reference to track, given the newest one and whether it is fresh.

    `track(ref, fresh, now)` → (reference point, state): LIVE (the newest reference),
    LANDING (stale: the last fresh one, its swing feet coming down) or STANDING (landed, or a
    fresh reference whose base is further than `resume_tolerance` from the stop's)."""

    def __init__(self, robot: RobotDescription, q_stand: np.ndarray, landing_time: float = LANDING_TIME,
                 resume_tolerance: float = RESUME_TOLERANCE) -> None:
        self.robot = robot
        self.ik = LegIK(robot, q_stand)
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, q_stand)
        self.ground = min(data.oMf[f].translation[2] for f in robot.foot_frame_ids)  # [m] a standing foot's height
        self.landing_time, self.resume_tolerance = landing_time, resume_tolerance
        self.stopped: ReferencePoint | None = None  # the last fresh reference before the stop
        self.since = 0.0                             # [s] when the stop began
        self.jump = 0.0                              # [m] base distance of the newest fresh reference

    def track(self, ref: ReferencePoint, fresh: bool, now: float) -> tuple[ReferencePoint, str]:
        if self.stopped is None:
            if fresh:
                return ref, LIVE
            self._stop(ref, now)
        elif fresh:
            self.jump = float(np.linalg.norm(ref.q[:3] - self.stopped.q[:3]))
            if self.jump <= self.resume_tolerance:
                self.stopped = None
                return ref, LIVE
        elapsed = now - self.since
        return self.landing(elapsed), LANDING if elapsed < self.landing_time else STANDING

    def _stop(self, ref: ReferencePoint, now: float) -> None:
        """Begin a stop at the last fresh reference: where its feet are, and where they land."""
        self.stopped, self.since = ref, now
        data = self.robot.model.createData()
        pin.framesForwardKinematics(self.robot.model, data, ref.q)
        self._feet0 = np.array([data.oMf[f].translation for f in self.robot.foot_frame_ids])
        self._drop = np.zeros_like(self._feet0)
        stance = np.asarray(ref.contacts, bool)
        # the ground is where the stance feet stand (the standing pose's feet if none does)
        ground = self._feet0[stance, 2].mean() if stance.any() else self.ground
        self._drop[~stance, 2] = ground - self._feet0[~stance, 2]
        rpy = pin.rpy.matrixToRpy(pin.Quaternion(*map(float, ref.q[[6, 3, 4, 5]])).toRotationMatrix())
        zero = np.zeros(3)
        self._base = BaseState(ref.q[:3].copy(), zero, zero, rpy, zero, zero)

    def landing(self, elapsed: float) -> ReferencePoint:
        """The stop's reference `elapsed` [s] after it began: the swing feet on a minimum-jerk
        drop to the ground over landing_time, then every foot a stance foot."""
        assert self.stopped is not None
        T = self.landing_time
        s, ds, dds = quintic(elapsed / T)
        q, v, a = self.ik.solve(self._base, self._feet0 + s * self._drop, ds / T * self._drop,
                                dds / T ** 2 * self._drop, guess=self.stopped.q[7:])
        contacts = self.stopped.contacts.copy() if s < 1.0 else np.ones_like(self.stopped.contacts)
        return replace(self.stopped, q=q, v=v, a=a, contacts=contacts)
