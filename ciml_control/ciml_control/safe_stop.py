"""What the controller tracks when its reference is late: feet down, then stand, and
resume only a reference that is still where the robot is.

Measured headless (HyQ, trot_35, nominal plant; ciml_sim/test/test_safe_stop.py): with the
last pose held, a reference that stalls does not drop the robot while it is stale, but its
return does: the motion went on while the robot stood, the base task chases that jump, and
the robot falls within ~1.5 s. After 1 s the return dropped HyQ at 4 of 4 gait phases, after
0.1 s (about 3.5 cm) at 3 of 4; 0.08 s (2.8 cm) brought the base down to 0.85 of its height.
Hence:
- stale: the base and the stance feet hold the last reference; each swing foot goes straight
  down to the ground (leg inverse kinematics, minimum-jerk over `landing_time`), then the
  robot stands on all feet. Moving the swing legs to the standing posture instead put a
  foot that touched down early where the posture's foot is not, and rolled the base;
- fresh again: resumed only if the reference's base is within `resume_tolerance`
  (horizontally) of the pose the robot stopped at; otherwise the robot keeps standing until
  the motion restarts. A fresh reference that moved further from the one before than its
  speed allows in the controller's time, by more than that tolerance (live: a reference
  node stopped for 0.3 s first sent its pre-stall instant, then caught up), stops the robot
  the same way.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from ciml_learning.core.robot import RobotDescription

from .references import BaseState, LegIK, ReferencePoint, quintic

LANDING_TIME = 0.2       # [s] swing feet to the ground: about half a trot cycle, a swing's own length
RESUME_TOLERANCE = 0.02  # [m] horizontal base jump a resumed reference may have (headless: 2.8 cm dropped HyQ)

LIVE, LANDING, STANDING = "live", "landing", "standing"


class SafeStop:
    """The reference to track, given the newest one and whether it is fresh.

    `track(ref, fresh, now)` → (reference point, state); `now` [s] is the stamp of the robot's
    sample being answered (the controller's clock may lag behind it). States: LIVE (the newest
    reference), LANDING (stale: the last fresh one, its swing feet coming down) or STANDING
    (landed, or a fresh reference further than `resume_tolerance` from the stop's)."""

    def __init__(self, robot: RobotDescription, q_stand: np.ndarray, landing_time: float = LANDING_TIME,
                 resume_tolerance: float = RESUME_TOLERANCE) -> None:
        self.robot = robot
        self.ik = LegIK(robot, q_stand)
        data = robot.model.createData()
        pin.framesForwardKinematics(robot.model, data, q_stand)
        self.ground = min(data.oMf[f].translation[2] for f in robot.foot_frame_ids)  # [m] a standing foot's height
        self.landing_time, self.resume_tolerance = landing_time, resume_tolerance
        self.stopped: ReferencePoint | None = None  # the last fresh reference before the stop
        self.previous: ReferencePoint | None = None  # the newest reference tracked live
        self.previous_now = 0.0                      # [s] when it was
        self.since = 0.0                             # [s] when the stop began
        self.jump = 0.0                              # [m] base distance of the newest fresh reference

    def track(self, ref: ReferencePoint, fresh: bool, now: float) -> tuple[ReferencePoint, str]:
        if self.stopped is None:
            previous, previous_now = self.previous, self.previous_now
            if ref is not previous:
                # the time of a reference is when it first came: one held for a few samples (its node
                # was late, still fresh) and then caught up moved over all of them, not over one
                self.previous, self.previous_now = ref, now
            if not fresh:
                self._stop(ref, now)
            elif previous is None or ref is previous or \
                    self._leap(previous, ref, now - previous_now) <= self.resume_tolerance:
                return ref, LIVE
            else:  # the reference moved further than its speed allows in the controller's time
                self._stop(previous, now)
        if fresh:
            assert self.stopped is not None
            self.jump = self._distance(ref, self.stopped)
            if self.jump <= self.resume_tolerance:
                self.stopped, self.previous, self.previous_now = None, ref, now
                return ref, LIVE
        elapsed = now - self.since
        return self.landing(elapsed), LANDING if elapsed < self.landing_time else STANDING

    @staticmethod
    def _distance(a: ReferencePoint, b: ReferencePoint) -> float:
        """Horizontal distance of two references' bases [m] (a gait keeps its height)."""
        return float(np.linalg.norm(a.q[:2] - b.q[:2]))

    @classmethod
    def _leap(cls, a: ReferencePoint, b: ReferencePoint, elapsed: float) -> float:
        """How much further than its own speed allows in `elapsed` [s] of the controller's clock
        the base moved from reference a to b [m, horizontal]: a reference node that stalls and
        catches up, or restarts elsewhere, leaps; one that skips samples while the simulation
        waits (lockstep) does not."""
        speed = max(float(np.linalg.norm(a.v[:2])), float(np.linalg.norm(b.v[:2])))  # base frame: |v| is kept
        return cls._distance(a, b) - speed * max(elapsed, 0.0)

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
        rpy = pin.rpy.matrixToRpy(pin.Quaternion(ref.q[3:7]).matrix())
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
