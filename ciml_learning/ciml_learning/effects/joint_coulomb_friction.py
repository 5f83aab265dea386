"""Joint Coulomb friction f_c [Nm]: a torque −f_c sign(q̇) after the torque sensor (in Φ̃, not Γ).

Candidate column: e_{6+j} = LP(tanh(q̇_j / v_s)) (diagnosis/candidates.py), θ = f_c ∈ [0, ½ τ_max].
MuJoCo: the joint's `frictionloss` — an implicit constraint with true stiction, made near-ideal as in
CIML's plant (FRICTION_SOLIMP), where the diagnosis' regressor is a tanh-smoothed sign (docs/DIAGNOSIS.md).
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

FRICTION_SOLIMP = (0.9999, 0.9999, 0.001, 0.5, 2.0)
"""MuJoCo's joint-friction constraint made close to ideal Coulomb friction: with friction_solref's
reference acceleration (the friction tries to stop the joint within a step or two) and almost no
regularisation, the force is ±value whenever the joint keeps sliding, and smaller only in
the step in which it sticks. CIML's plant uses it, and the export writes it unless the joint states its own."""


def friction_solref(timestep: float) -> tuple[float, float]:
    """solref of the near-ideal joint friction (FRICTION_SOLIMP) for a model's timestep [s]."""
    return 2 * timestep, 1.0


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

    def stiction(self, params):
        return float(params["value"])

    def patch_mjcf(self, patch, effect):
        patch.add_joint_attribute(effect["joint"], "frictionloss", effect["params"]["value"])
        patch.set_joint_default(effect["joint"], "solreffriction", friction_solref(patch.timestep()))
        patch.set_joint_default(effect["joint"], "solimpfriction", FRICTION_SOLIMP)


EFFECT = JointCoulombFriction()
