"""Link mass scale in the simulator: the link's inertia in the true model scaled by s (its mass and
its rotational inertia about its CoM)."""
from __future__ import annotations

import pinocchio as pin

from ciml_learning.core.errors import CimlError

from .base import SimEffect


class LinkMassScale(SimEffect):
    name = "link_mass_scale"
    changes_inertia = True

    def inertial(self, robot, model, effect):
        found = robot.link_inertias.get(effect.link) if effect.link else None
        if found is None:
            raise CimlError(f"link {effect.link!r} has no inertial in {robot.urdf_path}")
        joint, inertia = found
        s = effect.params["value"] - 1.0
        # dynamic parameters are linear in the inertia: adds s times the link (s < 0 removes mass)
        model.inertias[joint] = pin.Inertia.FromDynamicParameters(
            model.inertias[joint].toDynamicParameters() + s * inertia.toDynamicParameters())

    def force(self, truth, effect, j):
        return truth.inertial_force(effect)


EFFECT = LinkMassScale()
