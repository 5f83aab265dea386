"""How much of a learned model error ε the controller trusts: one law for the live
`id_controller` node and the headless closed loop (docs/LIVE_GRAPH.md, "Safety").

ε = J'ᵀΦ̃' − SᵀΓ (eq. 17) enters the feedforward QP (eq. 18–21) as a generalized force.
A learned model is only right where it has seen data, and a poisoned one (a learned fall,
a corrupted file) can be wrong everywhere, so per entry i of ε (nv: base wrench, joints):

1. Gate by confidence: a predicted entry (of the rigid-body error and of Γ) is used only if
   its predictive variance is at most `max_variance_ratio` × its prior variance σ₀² — the
   variance of "we do not know", the nominal model's (models.default_scaling,
   serving.nominal_prediction: 5 % of the weight for base forces, ×0.1 m for base torques, a
   quarter of it per foot, 5 % of each torque limit per joint). A model less certain than
   the prior has nothing to add; the entry falls back to the nominal model (0).
2. Clip to physics: |ε_i| ≤ the robot's physical bound (ciml_learning.core.physical_bounds:
   m·g for base forces, m·g·leg span for base torques, the torque limit per joint).

Without variances (an identified physical model, `ciml diagnose`'s effects) only the clip
applies. Every gated and every clipped step is counted by the caller.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ciml_learning.core.dynamics import selection_matrix
from ciml_learning.core.extraction import combined_error
from ciml_learning.core.physical_bounds import physical_bounds
from ciml_learning.core.robot import RobotDescription
from ciml_learning.learning.models import default_scaling

DEFAULT_MAX_VARIANCE_RATIO = 1.0
"""Trust an entry whose predictive variance is at most the prior's (the model knows more
than "we do not know")."""

GENERALIZED = "generalized"
"""The rigid-body part of a prediction as a model set predicts it: Φ̃ = J'ᵀΦ̃' (nv)."""


@dataclass
class TrustedEpsilon:
    """ε after the law, and what the law did this step."""

    epsilon: np.ndarray       # (nv,) the ε the controller uses
    gated: np.ndarray         # (n_rbd + n_j,) bool: predicted entry replaced by 0 (variance above the gate)
    clipped: np.ndarray       # (nv,) bool: ε entry clipped to its physical bound

    @property
    def n_gated(self) -> int:
        return int(self.gated.sum())

    @property
    def n_clipped(self) -> int:
        return int(self.clipped.sum())


class TrustLaw:
    """The gate and the clip of the module docstring for one robot.

    The gate applies to the entries the model predicted, in the coordinates it predicted them
    (a variance does not survive a change of coordinates without its covariances): the
    rigid-body part (Φ̃, or Φ̃' with the prior mapped like the prediction) and the actuation
    part Γ, each against the nominal model's prior variance of the same entry; ε is then
    formed (eq. 17) and clipped.
    """

    def __init__(self, robot: RobotDescription, max_variance_ratio: float = DEFAULT_MAX_VARIANCE_RATIO) -> None:
        if not max_variance_ratio > 0:
            raise ValueError(f"max_variance_ratio must be positive, got {max_variance_ratio}")
        _, _, out_scale = default_scaling(robot)
        nv = robot.nv
        self.prior_variance = {GENERALIZED: out_scale[:nv] ** 2, "actuation": out_scale[nv:] ** 2}
        self.max_variance_ratio = float(max_variance_ratio)
        self.bound = np.asarray(physical_bounds(robot).generalized, dtype=float)
        self.S = selection_matrix(robot)

    def gate(self, mean: np.ndarray, variance: np.ndarray | None, prior_variance: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
        """(mean with untrusted entries set to 0, gated mask). Without variance only non-finite
        entries are gated."""
        mean = np.asarray(mean, dtype=float)
        gated = ~np.isfinite(mean)
        if variance is not None:
            gated |= ~(np.asarray(variance, dtype=float) <= self.max_variance_ratio * prior_variance)
        return np.where(gated, 0.0, mean), gated

    def clip(self, epsilon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ε within the physical bounds, clipped mask)."""
        eps = np.where(np.isfinite(epsilon), epsilon, 0.0)
        clipped = np.abs(eps) > self.bound
        return (np.clip(eps, -self.bound, self.bound) if clipped.any() else eps), clipped

    def apply(self, rbd: np.ndarray, rbd_variance: np.ndarray | None, gamma: np.ndarray,
              gamma_variance: np.ndarray | None, basis: np.ndarray | None = None) -> TrustedEpsilon:
        """ε (eq. 17) from a prediction after the gate and the clip. basis None: rbd is Φ̃
        (generalized, a model set's output) and ε = Φ̃ − SᵀΓ; else rbd is Φ̃' and basis is J'
        (projection.contact_invariant_basis at the reference): ε = J'ᵀΦ̃' − SᵀΓ."""
        prior = self.prior_variance[GENERALIZED]
        if basis is not None and rbd_variance is not None:
            # the prior of Φ̃ mapped to Φ̃' as the model server maps the predicted variance
            # (serving.predict_at_reference: Φ̃' = J'⁻ᵀΦ̃, independent entries)
            prior = np.linalg.inv(basis.T) ** 2 @ prior
        rbd_t, gated_rbd = self.gate(rbd, rbd_variance, prior)
        gamma_t, gated_act = self.gate(gamma, gamma_variance, self.prior_variance["actuation"])
        eps = combined_error(basis, rbd_t, gamma_t, self.S)
        eps, clipped = self.clip(eps)
        return TrustedEpsilon(eps, np.concatenate([gated_rbd, gated_act]), clipped)


class TrustedEpsilonFunction:
    """epsilon_fn(ref) → ε after the TrustLaw, for the headless closed loop
    (ciml_sim.recorder.run_headless): wraps an epsilon_fn; if it offers the model set's
    prediction with variances (model_epsilon.EpsilonFunction.predict) the gate applies, else the
    clip only (an identified physical model has no variance). Counts the steps with a gated /
    clipped entry in `counts`."""

    def __init__(self, robot: RobotDescription, epsilon_fn, max_variance_ratio: float = DEFAULT_MAX_VARIANCE_RATIO
                 ) -> None:
        self.law = TrustLaw(robot, max_variance_ratio)
        self.epsilon_fn = epsilon_fn
        self._predict = getattr(epsilon_fn, "predict", None) if hasattr(epsilon_fn, "model_set") else None
        self._nv = robot.nv
        self._nj = robot.n_joints
        self.counts = {"epsilon_gated": 0, "epsilon_clipped": 0, "steps": 0}

    def __call__(self, ref) -> np.ndarray:
        if self._predict is not None:
            out = self._predict(ref)
            if out is None:  # non-finite reference: nominal model
                out = (np.full(self._nv, np.nan), None, np.full(self._nj, np.nan), None)
            trusted = self.law.apply(*out)
        else:
            eps, clipped = self.law.clip(np.asarray(self.epsilon_fn(ref), dtype=float))
            trusted = TrustedEpsilon(eps, np.zeros(0, dtype=bool), clipped)
        self.counts["steps"] += 1
        self.counts["epsilon_gated"] += bool(trusted.gated.any())
        self.counts["epsilon_clipped"] += bool(trusted.clipped.any())
        return trusted.epsilon
