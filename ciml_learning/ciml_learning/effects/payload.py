"""Payload: a point mass m [kg] at c [m] in the trunk frame (rigid body, in Φ̃).

Candidate columns: the root body's inertial-parameter regressor, Δπ_root of a point mass
(θ = m, m c; the rotational inertia m(‖c‖² I − c cᵀ) rides on the mass column once c is refined,
identification.fit_model). Bounds: m ≤ robot mass, ‖c‖ ≤ 1 m. MuJoCo: a body welded to the base
with that mass at c and the point mass's inertia (a tiny diagonal: MuJoCo needs a positive one).
"""
from __future__ import annotations

import numpy as np

from ciml_learning.effects.base import Candidate, EffectType, Field

PAYLOAD_MASS_FRACTION = 1.0
"""A payload weighs at most this multiple of the robot's own mass."""
PAYLOAD_LEVER = 1.0
"""[m] a payload's CoM lies at most this far from the base origin."""


def point_mass_rotational(com: np.ndarray) -> np.ndarray:
    """Rotational inertia about the origin of a unit point mass at `com`, in Pinocchio's
    dynamic-parameter order (Ixx, Ixy, Iyy, Ixz, Iyz, Izz): ‖c‖² I − c cᵀ."""
    c = np.asarray(com, float)
    inertia = np.dot(c, c) * np.eye(3) - np.outer(c, c)
    return inertia[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]]


class Payload(EffectType):
    name = "payload"
    fields = {"mass": Field("float", "kg", 0.0, 100.0), "com": Field("vec3", "m", -1.0, 1.0)}
    null = {"mass": 0.0, "com": [0.0, 0.0, 0.0]}
    wording = "an extra mass carried by the base"
    mujoco = "a body welded to the base (inertial: mass, pos)"

    def theta_bounds(self, robot, joint):
        m_max = PAYLOAD_MASS_FRACTION * float(robot.total_mass)
        mc = m_max * PAYLOAD_LEVER
        return (0.0, -mc, -mc, -mc), (m_max, mc, mc, mc)

    def physical_range(self, robot):
        return {"mass": [0.0, PAYLOAD_MASS_FRACTION * float(robot.total_mass)], "com_norm_max": PAYLOAD_LEVER}

    def physical_violation(self, params):
        com = np.asarray(params.get("com", [0, 0, 0]), float)
        if np.linalg.norm(com) > PAYLOAD_LEVER * (1 + 1e-6):
            return f"CoM {np.linalg.norm(com):.3g} m from the base (> {PAYLOAD_LEVER} m)"
        return None

    def candidates(self, layout):
        return [((2, 0, 0), Candidate(self.name, "rbd", ("mass", "mass_com_x", "mass_com_y", "mass_com_z"),
                                      *self.theta_bounds(layout.robot, None),
                                      tuple(range(layout.root0, layout.root0 + 10))))]

    refined_by = "payload_com"

    def matrix(self, layout, cand, A, refinement):
        r0 = layout.root0
        A[r0, 0] = 1.0
        if refinement.payload_com is not None:
            A[r0 + 4:r0 + 10, 0] = point_mass_rotational(refinement.payload_com)
        for k in range(3):
            A[r0 + 1 + k, 1 + k] = 1.0

    def to_physical(self, theta, cand, conv):
        m = float(theta[0])
        com = (theta[1:4] / m).tolist() if m > 1e-9 else [0.0, 0.0, 0.0]
        return {"mass": m, "com": [float(x) for x in com]}

    def to_theta(self, params, cand, conv):
        m, com = float(params["mass"]), np.asarray(params["com"], float)
        return np.concatenate([[m], m * com])

    def feature_theta(self, layout, cand, params, conv):
        return layout.matrix(cand, payload_com=np.asarray(params["com"], float)) @ self.to_theta(params, cand, conv)

    def patch_mjcf(self, patch, effect):
        patch.add_payload(effect["params"]["mass"], effect["params"]["com"])


EFFECT = Payload()
