"""Torque gain g: the actuator delivers τ = g ℓ (ℓ the lagged command), in Γ.

Candidate column: Γ_j = a τ_j, a = 1 − 1/g, g ∈ [0.5, 2]. MuJoCo: the actuator's gain
(gainprm[0] × g; a motor's bias is unchanged).
"""
from __future__ import annotations

from ciml_learning.effects.base import TORQUE_GAIN, Candidate, EffectType, Field, gain_theta


class TorqueGain(EffectType):
    name = "torque_gain"
    fields = {"joint": Field("joints"), "value": Field("float", "", 0.1, 2.0)}
    kind = "actuation"
    null = {"value": 1.0}
    wording = "the actuator delivers this multiple of the commanded torque"
    mujoco = "actuator gainprm[0] × gain"

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
        return [((4, j, 1), Candidate(self.name, "actuation", ("one_minus_inverse_gain",),
                                      *self.theta_bounds(layout.robot, name), (layout.actuation_feature(j, "gain"),),
                                      joint=name))
                for j, name in enumerate(layout.robot.joint_names)]

    def to_physical(self, theta, cand, conv):
        return {"value": 1.0 / (1.0 - float(theta[0]))}

    def to_theta(self, params, cand, conv):
        g = float(params["value"])
        if not g > 0 or g == float("inf"):
            raise ValueError(f"torque_gain of {cand.joint}: invalid value {g}")
        return [1.0 - 1.0 / g]

    def patch_mjcf(self, patch, effect):
        patch.scale_actuator_gain(effect["joint"], effect["params"]["value"])


EFFECT = TorqueGain()
