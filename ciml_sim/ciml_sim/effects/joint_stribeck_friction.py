"""Joint Stribeck friction in the simulator: a frictionloss whose level follows the Stribeck curve
of the current speed, coulomb + (breakaway − coulomb)·exp(−(q̇/velocity)²), set between steps."""
from __future__ import annotations

import numpy as np

from .base import SimEffect, joint_force


class JointStribeckFriction(SimEffect):
    name = "joint_stribeck_friction"
    between_steps = True
    frictionloss = True

    def configure(self, plant, effect, j):
        plant.friction_levels.append((effect, j))

    def friction_level(self, effect, qd):
        p = effect.params
        return p["coulomb"] + (p["breakaway"] - p["coulomb"]) * np.exp(-(qd / p["velocity"]) ** 2)

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, truth.friction_share[j] * truth.levels[id(effect)])


EFFECT = JointStribeckFriction()
