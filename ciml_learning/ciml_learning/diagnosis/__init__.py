"""The sim-to-real gap diagnosis (docs/ARCHITECTURE.md §6): where the gap lies, which effect causes it, how far
it shrinks. Pure modules (no rclpy):

- candidates: the registry's effect types (ciml_learning/effects, docs/ARCHITECTURE.md §5) as regressors in the
  eq. (11) coordinates and in Γ;
- features: regression rows (observed Φ̃' entries and Γ) and their Gram matrices;
- bounds: the physical range of every catalogue parameter (an estimate on a bound is "not identified");
- identification: noise-normalised bounded fits, greedy selection on held-out data, the noise floor;
- uncertainty: intervals that cover the truth (block bootstrap sized by the residual's autocorrelation,
  held-out reproduction, the lag's sampling conversion, misspecification; docs/DIAGNOSIS.md);
- reference: what distinguishes logs from reference logs of the same robot (`--reference`);
- localization, shrink, report: the three answers; run: the whole diagnosis; files: the diagnosis
  directory (diagnosis.json, report.html, identified.py's identified_scenario.yaml); commands: `ciml diagnose`;
- effects: the identified effects as a model of ε (for `ciml closed-loop --model DIAG_DIR`).
"""
from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from ciml_learning.core.robot import RobotDescription
from ciml_learning.diagnosis.effects import DiagnosisError, EffectModel, effects_from_diagnosis
from ciml_learning.diagnosis.files import DIAGNOSIS_JSON, read_diagnosis_json

__all__ = ["DiagnosisError", "EffectModel", "load_epsilon_function", "diagnose"]


def diagnose(*args, **kwargs):
    """See ciml_learning.diagnosis.run.diagnose."""
    from ciml_learning.diagnosis.run import diagnose as _diagnose

    return _diagnose(*args, **kwargs)


def load_effect_model(robot: RobotDescription, diagnosis_dir: str) -> EffectModel:
    """The identified effects of DIR/diagnosis.json as an EffectModel (checks the robot)."""
    path = os.path.join(diagnosis_dir, DIAGNOSIS_JSON) if os.path.isdir(diagnosis_dir) else diagnosis_dir
    if not os.path.exists(path):
        raise DiagnosisError(f"no diagnosis.json in {diagnosis_dir}; run `ciml diagnose --out DIR` first")
    doc = read_diagnosis_json(path)  # size and nesting limits
    effects, smoothing = effects_from_diagnosis(doc)
    joints = doc["model"].get("joint_names")
    if joints is not None and list(joints) != list(robot.joint_names):
        raise DiagnosisError(f"{path} was made for joints {joints}, not this robot's {list(robot.joint_names)}")
    return EffectModel(robot, effects, smoothing)


def load_epsilon_function(robot: RobotDescription, diagnosis_dir: str) -> Callable[[object], np.ndarray]:
    """epsilon_fn(ref) → ε (nv), the model error of eq. (17), ε = J'ᵀΦ̃' − SᵀΓ, that the nominal model
    plus the identified effects predicts at a ReferencePoint (ref.t, ref.q, ref.v, ref.a, ref.contacts).

    Rigid-body effects are evaluated at (ref.q, ref.v, ref.a) (EffectModel.rbd_force). Actuation
    effects (Γ = a τ + b − c τ̇) need the torque, unknown at the reference: τ and τ̇ are the
    reference's (dynamics.ReferenceTorque, with the rigid-body effects to realise too).
    A non-finite result is replaced by zeros (the nominal model), never returned.
    """
    from ciml_learning.core.dynamics import ReferenceTorque, selection_matrix
    from ciml_learning.core.extraction import combined_error

    model = load_effect_model(robot, diagnosis_dir)
    S = selection_matrix(robot)
    reference_torque = ReferenceTorque(robot)

    def epsilon_fn(ref) -> np.ndarray:
        q, v, a = (np.asarray(x, float) for x in (ref.q, ref.v, ref.a))
        eps = model.rbd_force(q, v, a)
        if model.has_actuation:
            tau, tau_dot = reference_torque(ref, eps)
            eps = combined_error(None, eps, model.actuation_error(tau, tau_dot), S)
        if not np.all(np.isfinite(eps)):
            return np.zeros(robot.nv)
        return eps

    return epsilon_fn
