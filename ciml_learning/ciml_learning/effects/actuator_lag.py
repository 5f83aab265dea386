"""Actuator lag T [s]: the torque follows the command through a first-order lag, T ℓ̇ + ℓ = u (in Γ).

Candidate column: Γ_j = −c τ̇_j with c = T/g (g the joint's torque gain), per joint and one for
all joints; c is read back to T through how the logs sample the command
(identification.lag_time_constant, docs/DIAGNOSIS.md). Bounds: T ∈ [0, 100 ms]. MuJoCo: the
actuator's first-order dynamics, dyntype="filterexact" with dynprm = T.
"""
from __future__ import annotations

import numpy as np

from ciml_learning.effects.base import TORQUE_GAIN, Candidate, EffectType, Field

MAX_LAG = 0.1
"""[s] largest actuator time constant."""


class ActuatorLag(EffectType):
    name = "actuator_lag"
    fields = {"joints": Field("joints"), "time_constant": Field("float", "s", 0.0, 0.2)}
    kind = "actuation"
    null = {"time_constant": 0.0}
    wording = "the joint torque follows the command with a first-order lag of this time constant"
    mujoco = "actuator dyntype=filterexact, dynprm=time constant"

    def theta_bounds(self, robot, joint):
        return (0.0,), (MAX_LAG / TORQUE_GAIN[0],)

    def physical_range(self, robot):
        return {"time_constant": [0.0, MAX_LAG]}

    def physical_violation(self, params):
        T = params.get("time_constant", 0.0)
        if T > MAX_LAG * (1 + 1e-6) or T < -1e-9:
            return f"time_constant {T:.4g} s outside [0, {MAX_LAG}]"
        return None

    def candidates(self, layout):
        robot = layout.robot
        lo, hi = self.theta_bounds(robot, None)
        out = [((4, j, 0), Candidate(self.name, "actuation", ("lag_over_gain",), lo, hi,
                                     (layout.actuation_feature(j, "lag"),), joint=name))
               for j, name in enumerate(robot.joint_names)]
        out.append(((5, 0, 0), Candidate(self.name, "actuation", ("lag_over_gain",), lo, hi,
                                         tuple(layout.actuation_feature(j, "lag") for j in range(robot.n_joints)),
                                         joints=tuple(robot.joint_names))))
        return out

    refined_by = "lag_scale"

    def matrix(self, layout, cand, A, refinement):
        A[list(cand.features), 0] = 1.0
        if len(cand.joints) > 1 and refinement.lag_scale:  # the all-joint lag: c_j = T/g_j
            for name, scale in refinement.lag_scale.items():
                A[layout.actuation_feature(layout.robot.joint_names.index(name), "lag"), 0] = scale

    def to_physical(self, theta, cand, conv):
        # a joint's own lag: c = T/g; the all-joint lag's column already carries 1/g_j (fit_model)
        c = float(theta[0])
        T = conv.lag_time_constant(c, cand.joint) if conv.lag_time_constant is not None else c
        return {"time_constant": T * (conv.gain.get(cand.joint, 1.0) if cand.joint else 1.0)}

    def to_theta(self, params, cand, conv):
        return [float(params["time_constant"]) / conv.gain.get(cand.joint, 1.0)]

    def feature_theta(self, layout, cand, params, conv):
        if cand.joint:
            return super().feature_theta(layout, cand, params, conv)
        theta = np.zeros(layout.n_features)
        for j, name in enumerate(layout.robot.joint_names):
            theta[layout.actuation_feature(j, "lag")] += float(params["time_constant"]) / conv.gain.get(name, 1.0)
        return theta

    def patch_mjcf(self, patch, effect):
        joints = effect.get("joints", effect.get("joint"))
        for joint in patch.joints_of(joints):
            patch.set_actuator_lag(joint, effect["params"]["time_constant"])


EFFECT = ActuatorLag()
