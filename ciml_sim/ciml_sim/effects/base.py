"""How the simulator applies an effect type (ciml_sim.plant), one module per registered name.

A module's SimEffect says where in the plant's chain (command → joint loop → actuator → torque
sensor → joint → rigid bodies → sensors; ciml_sim.plant) the effect acts:

- configure(plant, effect, joints): adds its parameters to the plant's per-joint arrays (gain,
  offset, lag time constant, encoder offset, torque sensor, Coulomb and viscous friction, IMU tilt),
  which the compiled joint loop and MuJoCo's model then apply; effects of one type on one joint add up;
- inertial(robot, model, effect): changes the true Pinocchio model (payload, link mass), from which
  the MuJoCo model is built;
- friction_level / side_torque: evaluated in Python between physics steps (a frictionloss level that
  follows the speed; an explicit joint torque), for effects the compiled loop does not carry;
- force(truth, effect, joints): its generalized force in eq. (3) of the nominal model at the current
  instant (GroundTruth.effect_forces); None for measurement-only effects.
"""
from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import numpy as np


class Truth(NamedTuple):
    """What the effects' forces are computed from at one instant (Plant.ground_truth)."""

    nv: int
    vj: np.ndarray            # true joint velocities [rad/s]
    u: np.ndarray             # the joint loop's command [Nm]
    lag: np.ndarray           # the lag's state (the lagged command) [Nm]
    friction_share: np.ndarray | None  # per joint: the friction constraint force over its level
    levels: dict[int, np.ndarray]      # id(effect) → its frictionloss level now
    side: dict[int, np.ndarray]        # id(effect) → its explicit joint torque now
    lag_share: np.ndarray              # per joint: (lag state − u) / time constant
    inertial_force: Any       # (effect) → −(RNEA of the true model with it − nominal RNEA)


def joint_force(nv: int, j: np.ndarray, values) -> np.ndarray:
    """A generalized force (nv) with `values` on joints j."""
    f = np.zeros(nv)
    f[6 + j] = values
    return f


class SimEffect:
    """Base of ciml_sim's effect modules (module docstring)."""

    name: ClassVar[str]
    between_steps: ClassVar[bool] = False
    """Evaluated in Python between physics steps (friction_level or side_torque)."""
    frictionloss: ClassVar[bool] = False
    """Acts through MuJoCo's joint friction constraint (its force is shared by the levels)."""
    changes_inertia: ClassVar[bool] = False
    """Changes the true model's inertias (inertial)."""

    def configure(self, plant, effect, j: np.ndarray) -> None:
        """Add the effect's parameters to the plant's arrays (module docstring)."""

    def inertial(self, robot, model, effect) -> None:
        """Change the true Pinocchio model (inertial effects only)."""
        raise NotImplementedError(self.name)

    def friction_level(self, effect, qd: np.ndarray) -> np.ndarray:
        raise NotImplementedError(self.name)

    def side_torque(self, effect, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError(self.name)

    def force(self, truth: Truth, effect, j: np.ndarray) -> np.ndarray | None:
        """The effect's generalized force now; None: a measurement effect, no force."""
        return None
