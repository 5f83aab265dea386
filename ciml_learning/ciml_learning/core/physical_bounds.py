"""Physical bounds on model errors, derived from the robot description only (no tuning).

A model error larger than the robot could physically produce is not a model error but a
fall, a collision, a sensor fault or a poisoned model. The same bounds serve the three
gates of the live graph (docs/LIVE_GRAPH.md, "Safety"): the online learner does not learn
a target beyond them, the model server does not serve a model that predicts beyond them
on its own training inputs, and the controller clips ε to them.

- Base force [N]: the robot's weight m·g (a payload or a support that large is not an
  "error" of the model any more).
- Base torque [Nm]: m·g times the leg span, the largest lever arm a foot force has about
  the base origin (the feet at the standing posture).
- Foot force of Φ̃' [N]: m·g (what a foot can carry at most, the whole robot).
- Joint torque (the joint part of Φ̃ = J'ᵀΦ̃', the actuation error Γ, and ε) [Nm]: the
  joint's torque limit.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ciml_learning.core.robot import RobotDescription

GRAVITY = 9.81
"""[m/s²]"""
N_BASE = 6
"""The first rigid-body dimensions: the base wrench; the others are the leg joints'."""


@dataclass(frozen=True)
class PhysicalBounds:
    """Largest physically plausible magnitude of each model-error entry (module docstring)."""

    weight: float                  # m·g [N]
    leg_span: float                # [m]
    standing_height: float         # base height above flat ground at the standing posture [m]
    rbd_error: np.ndarray          # (6 + 3 n_feet,) bound on |Φ̃'| (robot.rbd_error_names order)
    generalized: np.ndarray        # (nv,) bound on |Φ̃| = |J'ᵀΦ̃'| and on |ε| (base wrench, joints)
    actuation_error: np.ndarray    # (n_j,) bound on |Γ| (joint order)

    def rbd_violation(self, phi: np.ndarray, scale: float = 1.0) -> str | None:
        """Name and value of the first Φ̃' entry beyond scale × its bound (None if all within)."""
        return _first_violation(phi, scale * self.rbd_error, self._rbd_names)

    def actuation_violation(self, gamma: np.ndarray, scale: float = 1.0) -> str | None:
        return _first_violation(gamma, scale * self.actuation_error, self._joint_names)

    def generalized_violation(self, eps: np.ndarray, scale: float = 1.0) -> str | None:
        return _first_violation(eps, scale * self.generalized, self._dof_names)

    # names for the one-line reasons (set by physical_bounds)
    _rbd_names: tuple[str, ...] = ()
    _joint_names: tuple[str, ...] = ()
    _dof_names: tuple[str, ...] = ()


def _first_violation(x: np.ndarray, bound: np.ndarray, names: tuple[str, ...]) -> str | None:
    x = np.asarray(x, dtype=float)
    bad = ~(np.abs(x) <= bound)  # NaN counts as beyond
    if not bad.any():
        return None
    i = int(np.argmax(bad))
    name = names[i] if i < len(names) else str(i)
    return f"{name} = {x[i]:.4g} beyond ±{bound[i]:.4g}"


@lru_cache(maxsize=8)
def _bounds(robot: RobotDescription) -> PhysicalBounds:
    from ciml_learning.core.dynamics import RigidBodyDynamics

    weight = robot.total_mass * GRAVITY
    q = robot.neutral_configuration().copy()  # base at the origin, level
    q[7:] = robot.standing_joints
    feet = RigidBodyDynamics(robot).foot_positions(q)
    leg_span = float(np.max(np.linalg.norm(feet, axis=1)))
    standing_height = float(-np.min(feet[:, 2]))
    limits = np.where(robot.torque_limits > 0, robot.torque_limits, np.inf)
    base = np.array([weight] * 3 + [weight * leg_span] * 3)
    rbd = np.concatenate([base, np.full(3 * robot.n_feet, weight)])
    generalized = np.concatenate([base, limits])
    for a in (rbd, generalized, limits):
        a.setflags(write=False)
    return PhysicalBounds(weight, leg_span, standing_height, rbd, generalized, limits,
                          tuple(robot.rbd_error_names), tuple(robot.joint_names), tuple(robot.dof_names))


def physical_bounds(robot: RobotDescription) -> PhysicalBounds:
    """The robot's PhysicalBounds (computed once per robot description)."""
    return _bounds(robot)
