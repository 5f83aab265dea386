"""Torque gain in the simulator: τ = g · (lagged command) in the compiled joint loop."""
from __future__ import annotations

from .base import SimEffect, joint_force


class TorqueGain(SimEffect):
    name = "torque_gain"

    def configure(self, plant, effect, j):
        plant.gain[j] += effect.params["value"] - 1.0

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, (effect.params["value"] - 1.0) * truth.lag[j])


EFFECT = TorqueGain()
