"""Joint viscous friction in the simulator: MuJoCo's joint damping (implicit), after the torque sensor."""
from __future__ import annotations

from .base import SimEffect, joint_force


class JointViscousFriction(SimEffect):
    name = "joint_viscous_friction"

    def configure(self, plant, effect, j):
        plant.viscous[j] += effect.params["value"]

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, -effect.params["value"] * truth.vj[j])


EFFECT = JointViscousFriction()
