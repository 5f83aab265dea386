"""Torque-sensor gain in the simulator: the compiled sensor reads g_s τ (the joint receives τ)."""
from __future__ import annotations

from .base import SimEffect


class TorqueSensorGain(SimEffect):
    name = "torque_sensor_gain"

    def configure(self, plant, effect, j):
        plant.sensor[j, 0] += effect.params["value"] - 1.0


EFFECT = TorqueSensorGain()
