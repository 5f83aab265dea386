"""Identified effects as a model: their generalized force at any state (for the controller).

An EffectModel is rebuilt from the data in diagnosis.json alone (types, locations, physical
parameters; no code): each effect maps back to its candidate's linear parameters θ and the
same regressors as the identification (candidates.py), evaluated at one state.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription
from ciml_learning.diagnosis.candidates import (
    COULOMB_SMOOTHING,
    JOINT_FEATURE_TYPES,
    N_ACT,
    SENSOR_TYPES,
    FeatureLayout,
    RegressorEvaluator,
    link_inertias,
)
from ciml_learning.effects import EFFECTS, Conversion, effect_type


class DiagnosisError(CimlError):
    """A diagnosis cannot be computed or a diagnosis.json cannot be used."""


def _find(layout: FeatureLayout, effect: dict):
    typ = effect.get("type")
    joints = effect.get("joints")
    if isinstance(joints, list) and len(joints) == 1:
        effect = {**effect, "joint": joints[0]}
    elif isinstance(joints, str) and joints != "all":
        effect = {**effect, "joint": joints}
    for cand in layout.candidates:
        if cand.type != typ:
            continue
        if "link" in effect and cand.link == effect["link"]:
            return cand
        if "joint" in effect and cand.joint == effect["joint"]:
            return cand
        if effect.get("joints") == "all" and len(cand.joints) > 1:
            return cand
        if not {"link", "joint", "joints"} & set(effect) and not cand.location():
            return cand  # a base effect (payload, IMU tilt): one per robot
    raise DiagnosisError(f"effect {effect!r} does not match this robot's candidates")


def feature_coefficients(layout: FeatureLayout, effects: Sequence[dict]) -> tuple[np.ndarray, list]:
    """Coefficients on the feature columns (candidates.py) of a list of effects given in the
    scenario's / diagnosis' terms ({type, joint|joints|link, params}); and the matched candidates.

    Each type converts its own parameters (EffectType.feature_theta); the actuation and sensor
    parameters of a joint convert together (a = 1 − 1/g, b = o/g, c = T/g: the joint's gains first)."""
    conv = Conversion()
    for e in effects:
        if e.get("type") in ("torque_gain", "torque_sensor_gain"):
            gains = conv.gain if e["type"] == "torque_gain" else conv.sensor_gain
            g = e.get("params", {}).get("value")
            if isinstance(g, bool) or not isinstance(g, (int, float)) or not np.isfinite(g) or g <= 0:
                raise DiagnosisError(f"{e['type']} of {e.get('joint')}: invalid value {g}")
            gains[str(e.get("joint"))] = float(g)
    theta = np.zeros(layout.n_features)
    matched = []
    for e in effects:
        cand = _find(layout, e)
        matched.append(cand)
        p = e.get("params", {})
        try:
            theta += effect_type(cand.type).feature_theta(layout, cand, p, conv)
        except (KeyError, TypeError, ValueError) as err:
            raise DiagnosisError(f"effect {e.get('type')}: invalid parameters {p!r} ({err})") from err
    if not np.all(np.isfinite(theta)):
        raise DiagnosisError("effects hold non-finite parameters")
    return theta, matched


class EffectModel:
    """Sum of identified effects: e(q, q̇, q̈) (Φ̃ convention, nv) and Γ(τ, τ̇) (n_j)."""

    def __init__(self, robot: RobotDescription, effects: Sequence[dict], coulomb_smoothing: float | None = None):
        self.robot = robot
        self.layout = FeatureLayout(robot, link_inertias(robot))
        self.coulomb_smoothing = coulomb_smoothing or COULOMB_SMOOTHING
        self.evaluator = RegressorEvaluator(robot, self.layout)
        lay = self.layout
        # torque-sensor effects change what is measured, not the torque the joint receives: no force
        self.theta, _ = feature_coefficients(lay, [e for e in effects if e.get("type") not in SENSOR_TYPES])
        self.has_rbd = bool(np.any(self.theta[:lay.n_rbd] != 0))
        self.has_actuation = bool(np.any(self.theta[lay.act0:] != 0))

    def rbd_force(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """e (nv): the effects' model error Φ̃ at (q, q̇, q̈) — minus the force they exert.

        Joint friction uses tanh(q̇/v_s) (no low-pass at a single state); the encoder-offset
        term keeps its inverse-dynamics part only (its contact-force part needs the unknown λ)."""
        lay = self.layout
        if not self.has_rbd:
            return np.zeros(self.robot.nv)
        coulomb = np.tanh(np.asarray(v[6:], float) / self.coulomb_smoothing)[None]
        no_contact = np.zeros((1, self.robot.n_feet), bool)
        extra = {t: EFFECTS[t].joint_features(np.asarray(v[6:], float)[None]) for t in JOINT_FEATURE_TYPES}
        E, _ = self.evaluator.chunk(q[None], v[None], a[None], no_contact, np.zeros((1, self.robot.nv)), coulomb,
                                    joint_extra=extra)
        return E[0] @ self.theta[:lay.n_rbd]

    def actuation_error(self, tau: np.ndarray, tau_dot: np.ndarray) -> np.ndarray:
        """Γ (n_j) = a τ + b − c τ̇ per joint (candidates.py)."""
        nj = self.robot.n_joints
        th = self.theta[self.layout.act0:].reshape(nj, N_ACT)
        return -th[:, 0] * tau_dot + th[:, 1] * tau + th[:, 2]


def effects_from_diagnosis(diagnosis: dict) -> tuple[list[dict], float | None]:
    """(effects, coulomb smoothing) from a diagnosis.json document; checks its format."""
    model = diagnosis.get("model")
    if not isinstance(model, dict) or model.get("format_version") != 1:
        raise DiagnosisError("diagnosis.json has no model of format_version 1; rerun `ciml diagnose`")
    effects = model.get("effects")
    if not isinstance(effects, list):
        raise DiagnosisError("diagnosis.json: model.effects must be a list")
    return effects, model.get("coulomb_smoothing")
