"""Torque offset in the simulator: τ = g · (lagged command) + o in the compiled joint loop."""
from __future__ import annotations

import numpy as np

from .base import SimEffect, joint_force


class TorqueOffset(SimEffect):
    name = "torque_offset"

    def configure(self, plant, effect, j):
        plant.offset[j] += effect.params["value"]

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, np.full(len(j), effect.params["value"]))


EFFECT = TorqueOffset()
