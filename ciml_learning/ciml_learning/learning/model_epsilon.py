"""ε at a reference from a model set: the correction the controller adds, eq. (17)."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ciml_learning.core.extraction import combined_error
from ciml_learning.learning.models import ModelSet


class EpsilonFunction:
    """ε = Φ̃(x) − Sᵀ Γ(x, τ_ref, τ̇_ref), eq. (17) with Φ̃ = J'ᵀΦ̃' learned directly, from a model set.

    Callable with a reference point (anything with .t, .q, .v, .a, .contacts — e.g.
    ciml_control.references.ReferencePoint, dynamics.ReferenceState): returns ε (nv,)
    [N, Nm] at the reference, the generalized force the controller adds to M q̈ + h. The
    actuation models are evaluated at the torque the reference asks for with the learned
    rigid-body error, and its rate (dynamics.ReferenceTorque: stateful, one per reference
    stream). Never returns NaN: a non-finite input or prediction gives zeros (the nominal
    model) and is counted in n_nonfinite.
    """

    def __init__(self, robot, model_set: ModelSet) -> None:
        from ciml_learning.core.dynamics import ReferenceTorque, selection_matrix

        model_set.check_robot(robot)
        self.robot = robot
        self.model_set = model_set
        self.reference_torque = ReferenceTorque(robot)
        self._S = selection_matrix(robot)
        index = {n: i for i, n in enumerate(model_set.input_names)}
        self._torque_columns = np.array([index[f"tau_{j}"] for j in robot.joint_names])
        self._rate_columns = np.array([index[f"taud_{j}"] for j in robot.joint_names])
        self.n_nonfinite = 0

    def predict(self, ref, reference_torque=None, foot_jacobians: np.ndarray | None = None
                ) -> tuple[np.ndarray, ...] | None:
        """(Φ̃, var, Γ, var) at a reference point, or None if its inputs are not finite (Γ is NaN
        when Φ̃ is). reference_torque: the stream's ReferenceTorque (default: this function's own);
        foot_jacobians: at ref.q, if the caller has them (else ReferenceTorque computes them)."""
        from ciml_learning.core.extraction import learning_inputs

        q, v, a = (np.asarray(z, dtype=float) for z in (ref.q, ref.v, ref.a))
        zeros = np.zeros(self.robot.n_joints)
        x = learning_inputs(q, v, a, zeros, zeros)[0]
        if not np.all(np.isfinite(x)) or not np.all(np.isfinite(q)):
            return None
        rbd, rbd_var = self.model_set.predict_part_one(x, "rbd")
        if not np.all(np.isfinite(rbd)):
            nan = np.full(self.robot.n_joints, np.nan)
            return rbd, rbd_var, nan, nan
        x[self._torque_columns], x[self._rate_columns] = (reference_torque or self.reference_torque)(
            ref, rbd, foot_jacobians)
        return (rbd, rbd_var, *self.model_set.predict_part_one(x, "actuation"))

    def epsilon(self, ref, return_var: bool = False):
        """ε (nv,) at a reference point; with return_var, also its variance per entry (nv,),
        from the predicted variances assuming independent dimensions."""
        nv = self.robot.nv
        out = self.predict(ref)
        eps = var = np.zeros(nv)
        if out is not None:
            rbd, rbd_var, gamma, gamma_var = out
            eps = combined_error(None, rbd, gamma, self._S)  # the set learns Φ̃ = J'ᵀΦ̃'
            var = rbd_var + self._S.T @ gamma_var
        if out is None or not (np.all(np.isfinite(eps)) and np.all(np.isfinite(var))):
            self.n_nonfinite += 1
            eps, var = np.zeros(nv), np.zeros(nv)
        return (eps, var) if return_var else eps

    def __call__(self, ref) -> np.ndarray:
        return self.epsilon(ref)


def load_epsilon_function(robot, model_dir: str) -> Callable[[Any], np.ndarray]:
    """epsilon_fn(ref) → ε (nv,) at a reference point from a trained model directory
    (for `ciml closed-loop --model MODEL_DIR` and ciml_sim.recorder.run_headless)."""
    return EpsilonFunction(robot, ModelSet.load(model_dir, robot))
