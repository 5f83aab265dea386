"""Base IMU tilt in the simulator: the orientation reading is rotated by (roll, pitch) (no force)."""
from __future__ import annotations

from .base import SimEffect


class BaseImuTilt(SimEffect):
    name = "base_imu_tilt"

    def configure(self, plant, effect, j):
        plant.imu_roll += effect.params["roll"]
        plant.imu_pitch += effect.params["pitch"]


EFFECT = BaseImuTilt()
