"""Torque-sensor offset in the simulator: the compiled sensor reads g_s τ + o_s."""
from __future__ import annotations

from .base import SimEffect


class TorqueSensorOffset(SimEffect):
    name = "torque_sensor_offset"

    def configure(self, plant, effect, j):
        plant.sensor[j, 1] += effect.params["value"]


EFFECT = TorqueSensorOffset()
