"""Joint Coulomb friction f_c [Nm]: a torque −f_c sign(q̇) after the torque sensor (in Φ̃, not Γ).

Candidate column: e_{6+j} = LP(tanh(q̇_j / v_s)) (diagnosis/candidates.py), θ = f_c ∈ [0, ½ τ_max].
MuJoCo: the joint's `frictionloss` — an implicit constraint with true stiction, where CIML's
regressor is a tanh-smoothed sign (docs/DIAGNOSIS.md, export).
"""
from __future__ import annotations

from .base import FRICTION_FRACTION, Candidate, EffectType, Field, joint_torque_limit, torque_limits


class JointCoulombFriction(EffectType):
    name = "joint_coulomb_friction"
    fields = {"joint": Field("joints"), "value": Field("float", "Nm", 0.0, 100.0)}
    null = {"value": 0.0}
    wording = "a constant friction torque opposing the joint's motion"
    mujoco = "joint frictionloss"
    speed_bins = True

    def theta_bounds(self, robot, joint):
        return (0.0,), (FRICTION_FRACTION * joint_torque_limit(robot, joint),)

    def physical_range(self, robot):
        return {"value": [0.0, FRICTION_FRACTION * float(min(torque_limits(robot)))],
                "of_torque_limit": FRICTION_FRACTION}

    def candidates(self, layout):
        return [((0, j, 0), Candidate(self.name, "rbd", ("value",), *self.theta_bounds(layout.robot, name),
                                      (layout.coulomb0 + j,), joint=name, group=f"joint_friction_level:{name}"))
                for j, name in enumerate(layout.robot.joint_names)]

    def to_physical(self, theta, cand, conv):
        return {"value": float(theta[0])}

    def to_theta(self, params, cand, conv):
        return [float(params["value"])]

    def patch_mjcf(self, patch, effect):
        patch.add_joint_attribute(effect["joint"], "frictionloss", effect["params"]["value"])


EFFECT = JointCoulombFriction()
