"""Encoder offset δ [rad]: the measured joint position is q + δ (a sensor effect: no force).

Candidate column: e = −∂(Mq̈+h)/∂q_j + ∂(J_cᵀλ)/∂q_j (diagnosis/candidates.py), θ = δ, |δ| ≤ 5°.
Not MuJoCo physics: it goes to sensor_calibration.yaml (subtract δ from the reading).
"""
from __future__ import annotations

from ciml_learning.effects.base import MAX_ANGLE, Candidate, EffectType, Field


class EncoderOffset(EffectType):
    name = "encoder_offset"
    fields = {"joint": Field("joints"), "value": Field("float", "rad", -0.2, 0.2)}
    measurement_only = True
    null = {"value": 0.0}
    wording = "the joint encoder reads the true position plus this offset"

    def theta_bounds(self, robot, joint):
        return (-MAX_ANGLE,), (MAX_ANGLE,)

    def physical_range(self, robot):
        return {"value": [-MAX_ANGLE, MAX_ANGLE]}

    def candidates(self, layout):
        return [((0, j, 2), Candidate(self.name, "rbd", ("value",), *self.theta_bounds(layout.robot, name),
                                      (layout.encoder0 + j,), joint=name))
                for j, name in enumerate(layout.robot.joint_names)]

    def to_physical(self, theta, cand, conv):
        return {"value": float(theta[0])}

    def to_theta(self, params, cand, conv):
        return [float(params["value"])]


EFFECT = EncoderOffset()
