"""Torque-sensor offset o_s [Nm]: the log holds τ_m = g_s τ + o_s (in Φ̃ and Γ).

Candidate columns: e_{6+j} = 1 and Γ_j = 1 with b_s = o_s/g_s, |o_s| ≤ 0.2 τ_max. Not MuJoCo
physics: sensor_calibration.yaml (subtract o_s from the reading).
"""
from __future__ import annotations

from ciml_learning.effects.base import OFFSET_FRACTION, TORQUE_GAIN, Candidate, EffectType, Field, joint_torque_limit


class TorqueSensorOffset(EffectType):
    name = "torque_sensor_offset"
    fields = {"joint": Field("joints"), "value": Field("float", "Nm", -50.0, 50.0)}
    kind = "sensor"
    measurement_only = True
    null = {"value": 0.0}
    wording = "the torque sensor adds this constant to its reading"

    def theta_bounds(self, robot, joint):
        o = OFFSET_FRACTION * joint_torque_limit(robot, joint) / TORQUE_GAIN[0]
        return (-o,), (o,)

    def physical_range(self, robot):
        return {"value_of_torque_limit": [-OFFSET_FRACTION, OFFSET_FRACTION]}

    def candidates(self, layout):
        return [((6, j, 1), Candidate(self.name, "sensor", ("offset_over_gain",),
                                      *self.theta_bounds(layout.robot, name),
                                      (layout.torque0 + j, layout.actuation_feature(j, "offset")), joint=name))
                for j, name in enumerate(layout.robot.joint_names)]

    def to_physical(self, theta, cand, conv):
        return {"value": float(theta[0]) * conv.sensor_gain.get(cand.joint, 1.0)}

    def to_theta(self, params, cand, conv):
        return [float(params["value"]) / conv.sensor_gain.get(cand.joint, 1.0)]


EFFECT = TorqueSensorOffset()
