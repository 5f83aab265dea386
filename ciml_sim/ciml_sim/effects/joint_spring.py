"""Joint spring in the simulator (out of the diagnosis' catalogue): an explicit joint torque
−stiffness (q − rest), set between steps."""
from __future__ import annotations

from .base import SimEffect, joint_force


class JointSpring(SimEffect):
    name = "joint_spring"
    between_steps = True

    def configure(self, plant, effect, j):
        plant.side_effects.append((effect, j))

    def side_torque(self, effect, q):
        return -effect.params["stiffness"] * (q - effect.params["rest"])

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, truth.side[id(effect)])


EFFECT = JointSpring()
