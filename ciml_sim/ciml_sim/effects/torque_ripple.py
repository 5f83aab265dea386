"""Joint torque ripple in the simulator (out of the diagnosis' catalogue): an explicit joint torque
amplitude·sin(2π q/period), set between steps."""
from __future__ import annotations

import numpy as np

from .base import SimEffect, joint_force


class TorqueRipple(SimEffect):
    name = "torque_ripple"
    between_steps = True

    def configure(self, plant, effect, j):
        plant.side_effects.append((effect, j))

    def side_torque(self, effect, q):
        return effect.params["amplitude"] * np.sin(2 * np.pi * q / effect.params["period"])

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, truth.side[id(effect)])


EFFECT = TorqueRipple()
