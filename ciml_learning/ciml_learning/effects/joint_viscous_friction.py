"""Joint viscous friction b [Nm s/rad]: a torque −b q̇ after the torque sensor (in Φ̃, not Γ).

Candidate column: e_{6+j} = q̇_j, θ = b ∈ [0, ½ τ_max / (1 rad/s)]. MuJoCo: the joint's `damping`
(the same law, integrated implicitly).
"""
from __future__ import annotations

from ciml_learning.effects.base import (
    FRICTION_FRACTION,
    Candidate,
    EffectType,
    Field,
    joint_torque_limit,
    torque_limits,
)


class JointViscousFriction(EffectType):
    name = "joint_viscous_friction"
    fields = {"joint": Field("joints"), "value": Field("float", "Nm s/rad", 0.0, 100.0)}
    null = {"value": 0.0}
    wording = "a friction torque proportional to the joint's speed"
    mujoco = "joint damping"
    speed_bins = True

    def theta_bounds(self, robot, joint):
        return (0.0,), (FRICTION_FRACTION * joint_torque_limit(robot, joint),)

    def physical_range(self, robot):
        return {"value": [0.0, FRICTION_FRACTION * float(min(torque_limits(robot)))],
                "of_torque_limit": FRICTION_FRACTION}

    def candidates(self, layout):
        return [((0, j, 1), Candidate(self.name, "rbd", ("value",), *self.theta_bounds(layout.robot, name),
                                      (layout.viscous0 + j,), joint=name))
                for j, name in enumerate(layout.robot.joint_names)]

    def to_physical(self, theta, cand, conv):
        return {"value": float(theta[0])}

    def to_theta(self, params, cand, conv):
        return [float(params["value"])]

    def patch_mjcf(self, patch, effect):
        patch.add_joint_attribute(effect["joint"], "damping", effect["params"]["value"])


EFFECT = JointViscousFriction()
