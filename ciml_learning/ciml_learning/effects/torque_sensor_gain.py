"""Torque-sensor gain g_s: the log holds τ_m = g_s τ while the joint receives τ (in Φ̃ and Γ).

Candidate columns: e_{6+j} = τ_m,j and Γ_j = τ_m,j with one parameter a_s = 1 − 1/g_s,
g_s ∈ [0.5, 2]. Not MuJoCo physics: sensor_calibration.yaml (divide the reading by g_s).
"""
from __future__ import annotations

from ciml_learning.effects.base import TORQUE_GAIN, Candidate, EffectType, Field, gain_theta


class TorqueSensorGain(EffectType):
    name = "torque_sensor_gain"
    fields = {"joint": Field("joints"), "value": Field("float", "", 0.1, 2.0)}
    kind = "sensor"
    measurement_only = True
    null = {"value": 1.0}
    wording = "the torque sensor reads this multiple of the joint's torque"

    def theta_bounds(self, robot, joint):
        lo, hi = gain_theta(TORQUE_GAIN)
        return (lo,), (hi,)

    def physical_range(self, robot):
        return {"value": list(TORQUE_GAIN)}

    def physical_violation(self, params):
        g = params.get("value", 1.0)
        if not (TORQUE_GAIN[0] * (1 - 1e-6) <= g <= TORQUE_GAIN[1] * (1 + 1e-6)):
            return f"gain {g:.4g} outside {list(TORQUE_GAIN)}"
        return None

    def candidates(self, layout):
        return [((6, j, 0), Candidate(self.name, "sensor", ("one_minus_inverse_gain",),
                                      *self.theta_bounds(layout.robot, name),
                                      (layout.sensor_gain0 + j, layout.actuation_feature(j, "gain")), joint=name))
                for j, name in enumerate(layout.robot.joint_names)]

    def to_physical(self, theta, cand, conv):
        return {"value": conv.sensor_gain[cand.joint]}

    def to_theta(self, params, cand, conv):
        g = float(params["value"])
        if not g > 0 or g == float("inf"):
            raise ValueError(f"torque_sensor_gain of {cand.joint}: invalid value {g}")
        return [1.0 - 1.0 / g]


EFFECT = TorqueSensorGain()
