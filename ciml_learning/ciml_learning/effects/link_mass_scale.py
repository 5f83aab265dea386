"""Link mass scale s: a link's true mass (and rotational inertia about its CoM) is s × the URDF's.

Candidate column: Y_joint(l) π_l (the link's inertial parameters through Pinocchio's joint-torque
regressor), θ = s − 1, s ∈ [0.2, 5]. MuJoCo: the body's `inertial` (mass and diaginertia × s).
"""
from __future__ import annotations

from ciml_learning.effects.base import Candidate, EffectType, Field

LINK_MASS_SCALE = (0.2, 5.0)
"""A link's true mass lies within this factor range of its URDF mass."""


class LinkMassScale(EffectType):
    name = "link_mass_scale"
    fields = {"link": Field("link"), "value": Field("float", "", 0.1, 5.0)}
    null = {"value": 1.0}
    wording = "the link is heavier or lighter than its URDF by this factor"
    mujoco = "body inertial (mass and inertia scaled)"

    def theta_bounds(self, robot, joint):
        return (LINK_MASS_SCALE[0] - 1.0,), (LINK_MASS_SCALE[1] - 1.0,)

    def physical_range(self, robot):
        return {"value": list(LINK_MASS_SCALE)}

    def candidates(self, layout):
        return [((3, k, 0), Candidate(self.name, "rbd", ("scale_minus_one",), *self.theta_bounds(layout.robot, None),
                                      (layout.link0 + k,), link=link.name))
                for k, link in enumerate(layout.links)]

    def to_physical(self, theta, cand, conv):
        return {"value": 1.0 + float(theta[0])}

    def to_theta(self, params, cand, conv):
        return [float(params["value"]) - 1.0]

    def patch_mjcf(self, patch, effect):
        patch.scale_body_inertial(effect["link"], effect["params"]["value"])


EFFECT = LinkMassScale()
