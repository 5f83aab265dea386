"""Torque offset o [Nm]: the actuator delivers τ = g ℓ + o, in Γ.

Candidate column: Γ_j = b with b = o/g, |o| ≤ 0.2 τ_max. MuJoCo: the actuator's bias
(biasprm[0] += o: a constant force added to the actuator's output).
"""
from __future__ import annotations

from ciml_learning.effects.base import OFFSET_FRACTION, TORQUE_GAIN, Candidate, EffectType, Field, joint_torque_limit


class TorqueOffset(EffectType):
    name = "torque_offset"
    fields = {"joint": Field("joints"), "value": Field("float", "Nm", -50.0, 50.0)}
    kind = "actuation"
    null = {"value": 0.0}
    wording = "the actuator adds this constant torque to the command"
    mujoco = "actuator biasprm[0] += offset (biastype affine)"

    def theta_bounds(self, robot, joint):
        o = OFFSET_FRACTION * joint_torque_limit(robot, joint) / TORQUE_GAIN[0]
        return (-o,), (o,)

    def physical_range(self, robot):
        return {"value_of_torque_limit": [-OFFSET_FRACTION, OFFSET_FRACTION]}

    def candidates(self, layout):
        return [((4, j, 2), Candidate(self.name, "actuation", ("offset_over_gain",),
                                      *self.theta_bounds(layout.robot, name), (layout.actuation_feature(j, "offset"),),
                                      joint=name))
                for j, name in enumerate(layout.robot.joint_names)]

    def to_physical(self, theta, cand, conv):
        return {"value": float(theta[0]) * conv.gain.get(cand.joint, 1.0)}

    def to_theta(self, params, cand, conv):
        return [float(params["value"]) / conv.gain.get(cand.joint, 1.0)]

    def patch_mjcf(self, patch, effect):
        patch.add_actuator_bias(effect["joint"], effect["params"]["value"])


EFFECT = TorqueOffset()
