"""Whether a snapshot of the online learner may reach the controller (docs/LIVE_GRAPH.md, "Safety").

"Confident" is measured, not assumed: a snapshot is served only if, on recent live samples
it was never trained on, it predicts the model error better than the nominal model (zero
error) does, output by output.

- Held-back window. The learner does not learn a sample whose stamp falls in the first
  `block` seconds of every `every` blocks (held_back: by stamp, so a replay holds back the
  same samples); it keeps the newest `window` of them. Whole blocks, not single samples:
  at 250 Hz a sample's neighbours are nearly the same state, and a model that has learned
  them would look good on it without having learned anything that generalises.
- Decision per output i of the model set (18 rigid-body Φ̃ = J'ᵀΦ̃', n_j actuation Γ): with
  at least `min_heldout` held-back samples where the output is observed, accept it if its
  mean squared error is at most (1 − margin) × the nominal model's (the mean square of the
  target: the nominal model predicts 0). A snapshot is served with its accepted outputs only
  (the others are removed: they predict 0, the nominal model) and refused whole when it has
  learned fewer than `min_learned` samples or no output is accepted.

The base outputs' targets depend on the legs' learned models (models.ModelSet.base_wrench_targets:
the stance legs' joint errors added back), evaluated with the snapshot's own leg models, as the
learner forms them when it learns.

Why these defaults: the one fall seen live (docs/LIVE_GRAPH.md) came while serving snapshots
learned from 400–530 samples; `min_learned` = 1000 keeps models of that size away whatever the
held-back samples say (with `min_heldout` = 200 held back, one in five, an output needs ~800
learned samples for a decision anyway; a trot keeps ~50 valid samples per second). A margin of 0.25 asks an
output to explain a quarter of the error variance: with a few hundred autocorrelated held-back
samples the estimate of either mean square varies by ~10–20 %, so a smaller margin would let
chance decide.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ciml_learning.core.physical_bounds import N_BASE

if TYPE_CHECKING:  # the learners' kernels are not loaded by the nodes that only read the settings
    from ciml_learning.learning.models import ModelSet

HELD_BACK = "held_back_samples"
"""The learner's counter of samples kept for validation instead of learned."""
ACCEPTED = "snapshots_accepted"
REFUSED_TOO_FEW = "snapshots_refused_too_few_samples"
REFUSED_NOT_BETTER = "snapshots_refused_not_better_than_nominal"
"""The gate's decisions (counters on the online learner's /diagnostics)."""


@dataclass(frozen=True)
class ValidationConfig:
    block: float = 0.5          # [s] of stamps per hold-back block
    every: int = 5              # one block in `every` is held back (20 %)
    window: int = 1500          # newest held-back samples kept (6 s of them, the last 30 s of stream)
    min_learned: int = 1000     # samples learned before any snapshot is served
    min_heldout: int = 200      # held-back samples, per output, for a decision on it
    margin: float = 0.25        # an output's MSE must be ≤ (1 − margin) × the nominal model's

    def __post_init__(self) -> None:
        if not (self.block > 0 and self.every >= 2 and self.window >= 1 and self.min_heldout >= 1
                and self.min_learned >= 0 and 0.0 <= self.margin < 1.0):
            raise ValueError(f"invalid validation settings {self}")

    def held_back(self, stamp_ns: int) -> bool:
        """True if the sample of this stamp is kept for validation, not learned."""
        return int(stamp_ns) // int(self.block * 1e9) % self.every == 0


class HeldBackWindow:
    """The newest `capacity` held-back samples (ring buffers): x, Φ̃ and its mask, Γ (NaN where
    not observed) and the leg coupling C, as the learner would have learned them."""

    def __init__(self, capacity: int, n_inputs: int, n_rbd: int, n_joints: int) -> None:
        self.capacity = int(capacity)
        self.X = np.zeros((capacity, n_inputs))
        self.rbd = np.zeros((capacity, n_rbd))
        self.observed = np.zeros((capacity, n_rbd), dtype=bool)
        self.gamma = np.zeros((capacity, n_joints))
        self.C = np.zeros((capacity, N_BASE, n_joints))
        self.size = 0
        self._next = 0

    def add(self, x: np.ndarray, rbd: np.ndarray, observed: np.ndarray, gamma: np.ndarray, C: np.ndarray) -> None:
        k = self._next
        self.X[k], self.rbd[k], self.observed[k], self.gamma[k], self.C[k] = x, rbd, observed, gamma, C
        self._next = (k + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def arrays(self) -> tuple[np.ndarray, ...]:
        """Copies of the filled rows (X, Φ̃, mask, Γ, C), for a snapshot handed to another thread."""
        n = self.size
        return tuple(a[:n].copy() for a in (self.X, self.rbd, self.observed, self.gamma, self.C))


@dataclass
class Validation:
    """The gate's decision on one snapshot."""

    decision: str                 # ACCEPTED, REFUSED_TOO_FEW or REFUSED_NOT_BETTER
    accepted: np.ndarray          # (n_outputs,) bool
    mse_model: np.ndarray         # (n_outputs,) on the held-back samples [N², Nm²] (NaN: too few)
    mse_nominal: np.ndarray
    n_heldout: np.ndarray         # (n_outputs,) held-back samples with the output observed
    learned: int

    @property
    def served(self) -> bool:
        return self.decision == ACCEPTED

    def summary(self) -> str:
        if self.decision == REFUSED_TOO_FEW:
            return f"{self.learned} samples learned, {int(self.n_heldout.max(initial=0))} held back"
        n_acc, n_held = int(self.accepted.sum()), int(self.n_heldout.max())
        return f"{n_acc}/{len(self.accepted)} outputs better than nominal on {n_held} held-back samples"

    def to_json(self, output_names: tuple[str, ...]) -> dict:
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        return {"decision": self.decision, "learned": int(self.learned),
                "outputs": {name: {"accepted": bool(a), "mse_model": num(m), "mse_nominal": num(n), "heldout": int(h)}
                            for name, a, m, n, h in zip(output_names, self.accepted, self.mse_model,
                                                        self.mse_nominal, self.n_heldout)}}


def validate(ms: ModelSet, heldout: tuple[np.ndarray, ...], learned: int, config: ValidationConfig) -> Validation:
    """The decision of the module docstring for model set `ms` on the held-back samples
    (HeldBackWindow.arrays()), after `learned` learned samples."""
    X, rbd, observed, gamma, C = heldout
    n_out = ms.n_outputs
    nan = np.full(n_out, np.nan)
    usable = np.hstack([observed, np.isfinite(gamma)]) & np.all(np.isfinite(X), axis=1)[:, None]
    n_heldout = usable.sum(axis=0)
    if learned < config.min_learned or len(X) == 0:
        return Validation(REFUSED_TOO_FEW, np.zeros(n_out, bool), nan, nan, n_heldout, learned)
    targets = np.hstack([rbd, np.nan_to_num(gamma)])
    targets[:, :N_BASE] = ms.base_wrench_targets(ms.standardize(X), rbd, observed, C)
    pred = ms.predict(X, return_var=False)
    residual = targets - np.hstack([pred.rbd, pred.actuation])
    mse_model, mse_nominal = nan.copy(), nan.copy()
    for i in np.flatnonzero(n_heldout >= config.min_heldout):
        rows = usable[:, i]
        mse_model[i] = np.mean(residual[rows, i] ** 2)
        mse_nominal[i] = np.mean(targets[rows, i] ** 2)
    with np.errstate(invalid="ignore"):
        accepted = (mse_model <= (1.0 - config.margin) * mse_nominal) & np.array(
            [m is not None for m in ms.models_])
    decision = ACCEPTED if accepted.any() else (
        REFUSED_TOO_FEW if not (n_heldout >= config.min_heldout).any() else REFUSED_NOT_BETTER)
    return Validation(decision, accepted, mse_model, mse_nominal, n_heldout, learned)


def keep_accepted(ms: ModelSet, validation: Validation) -> ModelSet:
    """The set with only its accepted outputs' models (in place: `ms` is the snapshot's own copy);
    a removed output predicts 0 with its prior variance, the nominal model."""
    for i in np.flatnonzero(~validation.accepted):
        ms.models_[i] = None
    return ms
