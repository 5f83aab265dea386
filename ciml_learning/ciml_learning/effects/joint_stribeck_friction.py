"""Joint Stribeck friction: a friction level that falls from the breakaway torque f_s at rest to the
Coulomb level f_c with speed, f(q̇) = −sign(q̇) [f_c + (f_s − f_c) exp(−(q̇/v_s)²)] (after the torque
sensor: in Φ̃, not Γ).

Candidate columns: the Coulomb column LP(tanh(q̇/v_c)) and LP(tanh(q̇/v_c) exp(−(q̇/v_s)²)) with
θ = (f_s − f_c, f_c) ≥ 0. The model is not linear in v_s: the layout holds the second column at
STRIBECK_VELOCITIES (half an octave apart), a v_s between two is the linear interpolation of its
neighbours in log v_s, and v_s is fitted by a 1-D search (identification.fit_model). A Stribeck
candidate nests the Coulomb one of its joint (group "joint_friction_level"): the two never enter
one model, and the extra parameters must pay for themselves. MuJoCo has no velocity-dependent
frictionloss: not exportable (the Coulomb part alone would be frictionloss = f_c).
"""
from __future__ import annotations

import math

import numpy as np

from ciml_learning.effects.base import (
    COULOMB_SMOOTHING,
    FRICTION_FRACTION,
    Candidate,
    EffectType,
    Field,
    joint_torque_limit,
    torque_limits,
)

STRIBECK_STEP = 2.0 ** 0.5
STRIBECK_VELOCITIES = tuple(0.05 * STRIBECK_STEP ** k for k in range(11))
"""[rad/s] the Stribeck velocities of the layout's columns (0.05 … 1.6, half an octave apart: an octave's
interpolation biased the breakaway level by ~25 %, outside its interval). The lowest is the speed below
which a joint may be stuck by its friction (diagnosis/shrink.V_STICK): a friction level that changes only
below it is the stick–slip transition a smoothed Coulomb law leaves, not a Stribeck curve, and a fit that
wants a lower velocity ends on the bound ("not identified")."""


class JointStribeckFriction(EffectType):
    name = "joint_stribeck_friction"
    fields = {"joint": Field("joints"), "breakaway": Field("float", "Nm", 0.0, 100.0),
              "coulomb": Field("float", "Nm", 0.0, 100.0), "velocity": Field("float", "rad/s", 1e-3, 5.0)}
    null = {"breakaway": 0.0, "coulomb": 0.0, "velocity": 0.0}
    wording = ("a friction torque opposing the joint's motion that falls from its breakaway level at rest "
               "to the Coulomb level above the Stribeck velocity")
    mujoco_note = "MuJoCo's frictionloss is one level at every speed: a Stribeck curve has no MuJoCo element"
    nonlinear = ("velocity", STRIBECK_VELOCITIES[0], STRIBECK_VELOCITIES[-1])
    joint_feature_count = len(STRIBECK_VELOCITIES)
    speed_bins = True
    may_vanish = ("coulomb",)  # a pure breakaway bump (f_c = 0) is a Stribeck curve too

    def check(self, params):
        if params["breakaway"] < params["coulomb"]:
            return f"breakaway: must be at least coulomb ({params['coulomb']}), got {params['breakaway']}"
        return None

    def theta_bounds(self, robot, joint):
        f = FRICTION_FRACTION * joint_torque_limit(robot, joint)
        return (0.0, 0.0), (f, f)

    def physical_range(self, robot):
        f = FRICTION_FRACTION * float(min(torque_limits(robot)))
        return {"breakaway": [0.0, 2 * f], "coulomb": [0.0, f], "velocity": [self.nonlinear[1], self.nonlinear[2]],
                "of_torque_limit": FRICTION_FRACTION}

    def candidates(self, layout):
        k = self.joint_feature_count
        s0 = layout.joint_feature0[self.name]
        return [((7, j, 0), Candidate(self.name, "rbd", ("breakaway_minus_coulomb", "coulomb"),
                                      *self.theta_bounds(layout.robot, name),
                                      (layout.coulomb0 + j,) + tuple(range(s0 + k * j, s0 + k * (j + 1))),
                                      joint=name, group=f"joint_friction_level:{name}"))
                for j, name in enumerate(layout.robot.joint_names)]

    refined_by = "nonlinear"

    def matrix(self, layout, cand, A, refinement):
        A[cand.features[0], 1] = 1.0
        v = (refinement.nonlinear or {}).get(cand.label, math.sqrt(STRIBECK_VELOCITIES[0] * STRIBECK_VELOCITIES[-1]))
        x = min(max(math.log(v / STRIBECK_VELOCITIES[0], STRIBECK_STEP), 0.0), len(STRIBECK_VELOCITIES) - 1.0)
        i = min(int(x), len(STRIBECK_VELOCITIES) - 2)
        w = x - i
        A[cand.features[1 + i], 0] = 1.0 - w
        A[cand.features[2 + i], 0] = w

    def to_physical(self, theta, cand, conv):
        return {"breakaway": float(theta[0] + theta[1]), "coulomb": float(theta[1]),
                "velocity": float(conv.nonlinear[cand.label])}

    def to_theta(self, params, cand, conv):
        return [float(params["breakaway"]) - float(params["coulomb"]), float(params["coulomb"])]

    def stiction(self, params):
        return float(params["breakaway"])

    def feature_theta(self, layout, cand, params, conv):
        A = layout.matrix(cand, nonlinear={cand.label: float(params["velocity"])})
        return A @ self.to_theta(params, cand, conv)

    def joint_features(self, v_joints):
        v = np.asarray(v_joints, float)[..., None]
        return np.tanh(v / COULOMB_SMOOTHING) * np.exp(-(v / np.asarray(STRIBECK_VELOCITIES)) ** 2)


EFFECT = JointStribeckFriction()
