"""Payload in the simulator: a point mass added to the trunk's inertia of the true model (the root
body when there is no trunk), from which MuJoCo's model is built."""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from .base import SimEffect


class Payload(SimEffect):
    name = "payload"
    changes_inertia = True

    def inertial(self, robot, model, effect):
        frame_name = "trunk" if model.existFrame("trunk") else model.frames[2].name
        frame = model.frames[model.getFrameId(frame_name)]
        point = pin.Inertia(effect.params["mass"], np.asarray(effect.params["com"], float), np.zeros((3, 3)))
        model.inertias[frame.parentJoint] = model.inertias[frame.parentJoint] + frame.placement.act(point)

    def force(self, truth, effect, j):
        return truth.inertial_force(effect)


EFFECT = Payload()
