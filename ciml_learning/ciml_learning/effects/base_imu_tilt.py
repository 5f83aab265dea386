"""Base IMU tilt (roll, pitch) [rad]: the orientation estimate is rotated by a body-frame tilt.

Candidate columns: e = −∂(Mq̈+h)/∂θ_{roll,pitch} (only gravity changes; the contact term drops out
because P_c is rotation-invariant), |angles| ≤ 5°. Not MuJoCo physics: sensor_calibration.yaml.
"""
from __future__ import annotations

from ciml_learning.effects.base import MAX_ANGLE, Candidate, EffectType, Field


class BaseImuTilt(EffectType):
    name = "base_imu_tilt"
    fields = {"roll": Field("float", "rad", -0.2, 0.2), "pitch": Field("float", "rad", -0.2, 0.2)}
    measurement_only = True
    null = {"roll": 0.0, "pitch": 0.0}
    wording = "the base orientation estimate is tilted by these angles"

    def theta_bounds(self, robot, joint):
        return (-MAX_ANGLE, -MAX_ANGLE), (MAX_ANGLE, MAX_ANGLE)

    def physical_range(self, robot):
        return {"roll": [-MAX_ANGLE, MAX_ANGLE], "pitch": [-MAX_ANGLE, MAX_ANGLE]}

    def candidates(self, layout):
        return [((1, 0, 0), Candidate(self.name, "rbd", ("roll", "pitch"), *self.theta_bounds(layout.robot, None),
                                      (layout.imu0, layout.imu0 + 1)))]

    def to_physical(self, theta, cand, conv):
        return {"roll": float(theta[0]), "pitch": float(theta[1])}

    def to_theta(self, params, cand, conv):
        return [float(params["roll"]), float(params["pitch"])]


EFFECT = BaseImuTilt()
