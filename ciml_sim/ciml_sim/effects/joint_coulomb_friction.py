"""Joint Coulomb friction in the simulator: MuJoCo's frictionloss (an implicit constraint: true
stiction, no chatter), after the torque sensor."""
from __future__ import annotations

from .base import SimEffect, joint_force


class JointCoulombFriction(SimEffect):
    name = "joint_coulomb_friction"
    frictionloss = True

    def configure(self, plant, effect, j):
        plant.coulomb[j] += effect.params["value"]

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, truth.friction_share[j] * effect.params["value"])


EFFECT = JointCoulombFriction()
