"""Actuator lag in the simulator: the compiled joint loop's first-order lag of the command
(backward Euler at 1 kHz), between command and torque sensor."""
from __future__ import annotations

from .base import SimEffect, joint_force


class ActuatorLag(SimEffect):
    name = "actuator_lag"

    def configure(self, plant, effect, j):
        plant.lag_time_constant[j] += effect.params["time_constant"]

    def force(self, truth, effect, j):
        return joint_force(truth.nv, j, truth.lag_share[j] * effect.params["time_constant"])


EFFECT = ActuatorLag()
