"""The sim-to-real gap diagnosis (DESIGN §6): where the gap lies, which effect causes it, how far
it shrinks. Pure modules (no rclpy):

- candidates: the effect catalogue (DESIGN §5) as regressors in the eq. (11) coordinates and in Γ;
- features: regression rows (observed Φ̃' entries and Γ) and their Gram matrices;
- identification: noise-normalised constrained fits, greedy selection on held-out data, bootstrap;
- localization, shrink, report: the three answers; run: the whole diagnosis; commands: `ciml diagnose`;
- effects: the identified effects as a model of ε (for `ciml closed-loop --model DIAG_DIR`).
"""
from __future__ import annotations

import json
import os
from collections.abc import Callable

import numpy as np

from ..robot import RobotDescription
from .effects import DiagnosisError, EffectModel, effects_from_diagnosis

__all__ = ["DiagnosisError", "EffectModel", "load_epsilon_function", "diagnose"]


def diagnose(*args, **kwargs):
    """See ciml_learning.diagnosis.run.diagnose."""
    from .run import diagnose as _diagnose

    return _diagnose(*args, **kwargs)


def load_effect_model(robot: RobotDescription, diagnosis_dir: str) -> EffectModel:
    """The identified effects of DIR/diagnosis.json as an EffectModel (checks the robot)."""
    path = os.path.join(diagnosis_dir, "diagnosis.json") if os.path.isdir(diagnosis_dir) else diagnosis_dir
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError as err:
        raise DiagnosisError(f"no diagnosis.json in {diagnosis_dir}; run `ciml diagnose --out DIR` first") from err
    except (OSError, json.JSONDecodeError) as err:
        raise DiagnosisError(f"cannot read {path}: {err}") from err
    effects, smoothing = effects_from_diagnosis(doc)
    joints = doc["model"].get("joint_names")
    if joints is not None and list(joints) != list(robot.joint_names):
        raise DiagnosisError(f"{path} was made for joints {joints}, not this robot's {list(robot.joint_names)}")
    return EffectModel(robot, effects, smoothing)


def load_epsilon_function(robot: RobotDescription, diagnosis_dir: str) -> Callable[[object], np.ndarray]:
    """epsilon_fn(ref) → ε (nv), the model error of eq. (17), ε = J'ᵀΦ̃' − SᵀΓ, that the nominal model
    plus the identified effects predicts at a ReferencePoint (ref.t, ref.q, ref.v, ref.a, ref.contacts).

    Rigid-body effects are evaluated at (ref.q, ref.v, ref.a) (EffectModel.rbd_force). Actuation
    effects (Γ = a τ + b − c τ̇) need the torque, unknown at the reference: τ is approximated by
    the least-norm joint torques that realise the reference with the given stance feet,
    τ_ref = (Q_uᵀSᵀ)⁺ Q_uᵀ (M q̈ + h + e) — the controller's QP without friction cones and
    weights — clipped to the torque limits, and τ̇ by the finite difference of τ_ref between
    consecutive calls (zero on the first call, after a time jump > 50 ms or backwards, and across
    a change of the contact schedule, where τ_ref jumps and one difference would be an impulse).
    A non-finite result is replaced by zeros (the nominal model), never returned.
    """
    import pinocchio as pin

    from ..dynamics import selection_matrix
    from ..projection import contact_jacobian

    model = load_effect_model(robot, diagnosis_dir)
    S = selection_matrix(robot)
    data = robot.model.createData()
    state = {"t": None, "tau": None, "contacts": None}

    def tau_reference(q, v, a, contacts, e):
        b = pin.rnea(robot.model, data, q, v, a) + e
        pin.computeJointJacobians(robot.model, data, q)
        pin.updateFramePlacements(robot.model, data)
        jac = np.array([pin.getFrameJacobian(robot.model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3]
                        for f in robot.foot_frame_ids])
        Jc = contact_jacobian(jac, contacts)
        if Jc.shape[0]:
            Q, _ = np.linalg.qr(Jc.T, mode="complete")
            Qu = Q[:, Jc.shape[0]:]
        else:
            Qu = np.eye(robot.nv)
        tau = np.linalg.lstsq(Qu.T @ S.T, Qu.T @ b, rcond=None)[0]
        return np.clip(tau, -robot.torque_limits, robot.torque_limits)

    def epsilon_fn(ref) -> np.ndarray:
        q, v, a = (np.asarray(x, float) for x in (ref.q, ref.v, ref.a))
        e = model.rbd_force(q, v, a)
        eps = e.copy()
        if model.has_actuation:
            contacts = np.asarray(getattr(ref, "contacts", np.ones(robot.n_feet, bool)), bool)
            tau = tau_reference(q, v, a, contacts, e)
            t = float(getattr(ref, "t", 0.0))
            dt = None if state["t"] is None else t - state["t"]
            same_contacts = state["contacts"] is not None and np.array_equal(contacts, state["contacts"])
            smooth = dt is not None and 0 < dt <= 0.05 and same_contacts
            tau_dot = (tau - state["tau"]) / dt if smooth else np.zeros_like(tau)
            state["t"], state["tau"], state["contacts"] = t, tau, contacts
            eps = eps - S.T @ model.actuation_error(tau, tau_dot)
        if not np.all(np.isfinite(eps)):
            return np.zeros(robot.nv)
        return eps

    return epsilon_fn
