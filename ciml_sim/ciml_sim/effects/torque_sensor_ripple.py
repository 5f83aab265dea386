"""Torque-sensor ripple in the simulator (out of the diagnosis' catalogue): the compiled sensor
reads + amplitude·sin(2π q/period) (one per joint)."""
from __future__ import annotations

import numpy as np

from ciml_learning.core.errors import CimlError

from .base import SimEffect


class TorqueSensorRipple(SimEffect):
    name = "torque_sensor_ripple"

    def configure(self, plant, effect, j):
        if np.any(plant.sensor[j, 2] != 0.0):
            raise CimlError("one torque_sensor_ripple per joint")
        plant.sensor[j, 2], plant.sensor[j, 3] = effect.params["amplitude"], effect.params["period"]


EFFECT = TorqueSensorRipple()
