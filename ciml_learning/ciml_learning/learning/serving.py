"""Model serving without ROS: the algorithms of the `model_server` node (docs/ARCHITECTURE.md §3).

- load_served_model loads and validates a model directory (ModelSet.load: version,
  allow-listed learner, robot names, the whole-model checksum; an announced model must
  carry that checksum; its predictions on its own training inputs stay within the robot's
  physical bounds) — any failure is a ModelFileError.
- predict_at_reference gives Φ̃' (18) and Γ (n_j) with variances at the reference (qᵈ, q̇ᵈ,
  q̈ᵈ and the torque it asks for, τ_ref, τ̇_ref: model_epsilon.EpsilonFunction.predict), or the
  nominal model (see PredictedError): the set predicts Φ̃ = J'ᵀΦ̃' and the server publishes
  Φ̃' = J'⁻ᵀΦ̃ with the basis at qᵈ, so the message keeps the contact-invariant coordinates
  of /model_error/measured.
- The node loads on a workers.LatestOnlyWorker thread and swaps the served model in its own
  thread, so the old model serves until the new one is ready (no gap); SwapHold says when.
"""
from __future__ import annotations

import io
import os
from dataclasses import dataclass

import numpy as np

from ciml_learning.core.dynamics import ReferenceState, ReferenceTorque, RigidBodyDynamics
from ciml_learning.core.extraction import learning_inputs
from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.core.robot import RobotDescription
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.model_files import ModelFileError, read_metadata, read_model_file
from ciml_learning.learning.models import ModelSet, default_scaling
from ciml_learning.learning.snapshots import PROBE_FILE


@dataclass
class ServedModel:
    """A validated model set as served by the model server."""

    name: str                 # "<learner>:<directory name>", the `source` of predictions
    model_dir: str
    model_set: ModelSet
    checksum: str
    rbd_learned: np.ndarray        # (18,) bool: entry of Φ̃' backed by learned models
    actuation_learned: np.ndarray  # (n_j,) bool
    dynamics: RigidBodyDynamics    # the server's own (the basis at the reference)
    epsilon: EpsilonFunction       # the set's predictions at a reference


def probe_inputs(robot: RobotDescription) -> np.ndarray:
    """Learning inputs x of the robot standing still without torque: a probe for validation."""
    q = robot.neutral_configuration().copy()
    q[7:] = robot.standing_joints
    zeros = np.zeros(robot.n_joints)
    return learning_inputs(q, np.zeros(robot.nv), np.zeros(robot.nv), zeros, zeros)[0]


def load_served_model(robot: RobotDescription, model_dir: str, checksum: str | None = None) -> ServedModel:
    """Load and validate a model directory for serving; ModelFileError (one line) if unusable.

    - ModelSet.load's checks: format version, allow-listed learner, model.json's own
      checksum, every file of its manifest, the robot's names.
    - Announced models (`checksum` not None: a /model_update) must carry the whole-model
      checksum (model.json's `checksum`, which covers the description and, through the
      manifest, every file); an empty or different one is refused.
    - Bounded predictions (check_predictions_within_bounds): on the model's own training
      inputs (the snapshot's probe_inputs.npy, else the set's input mean) and at the standing
      posture, every prediction finite and within the robot's physical bounds.
    """
    model_dir = os.path.abspath(os.path.expanduser(model_dir))
    meta = read_metadata(model_dir)
    stored = str(meta.get("checksum", ""))
    if checksum is not None:
        announced = str(checksum)
        if not announced:
            raise ModelFileError(f"{model_dir}: announced without a checksum (refused: only checksummed "
                                 "snapshots are served)")
        if stored != announced:
            raise ModelFileError(f"{model_dir}: model checksum {stored[:12]}… differs from the announced "
                                 f"{announced[:12]}… (replaced or tampered after the announcement)")
    ms = ModelSet.load(model_dir, robot)
    meta = read_metadata(model_dir)
    if str(meta.get("checksum", "")) != stored:
        raise ModelFileError(f"{model_dir} changed while it was being loaded")
    probes = [probe_inputs(robot), ms.input_mean_]
    if PROBE_FILE in meta["manifest"]:
        probes += list(_read_probe_file(model_dir, meta, ms))
    check_predictions_within_bounds(robot, ms, np.array(probes), model_dir)
    return served_model(robot, ms, f"{ms.learner}:{os.path.basename(model_dir)}", model_dir, stored)


def _read_probe_file(model_dir: str, meta: dict, ms: ModelSet) -> np.ndarray:

    try:
        x = np.asarray(np.load(io.BytesIO(read_model_file(model_dir, meta, PROBE_FILE)), allow_pickle=False),
                       dtype=float)
    except (ValueError, OSError, EOFError, TypeError) as err:
        raise ModelFileError(f"{model_dir}/{PROBE_FILE} is not a readable npy ({err})") from None
    if x.ndim != 2 or x.shape[1] != len(ms.input_names) or not np.all(np.isfinite(x)):
        raise ModelFileError(f"{model_dir}/{PROBE_FILE}: shape {x.shape} or values unusable "
                             f"(expected finite (k, {len(ms.input_names)}))")
    return x


def check_predictions_within_bounds(robot: RobotDescription, ms: ModelSet, inputs: np.ndarray,
                                    where: str = "model") -> None:
    """ModelFileError unless every prediction (Φ̃ = J'ᵀΦ̃' and Γ, means) at the rows of `inputs`
    is finite and within physical_bounds (base force m·g, base torque m·g·leg span, joint
    torques their limits): a model predicting more than the robot can produce has learned a
    fall or was corrupted (e.g. scaled)."""
    from ciml_learning.core.physical_bounds import physical_bounds

    bounds = physical_bounds(robot)
    for x in np.atleast_2d(inputs):
        rbd, _, gamma, _ = ms.predict_one(x)
        bad = bounds.generalized_violation(rbd) or bounds.actuation_violation(gamma)
        if bad:
            raise ModelFileError(f"{where}: prediction beyond physical bounds on its own training inputs ({bad})")


def served_model(robot: RobotDescription, ms: ModelSet, name: str, model_dir: str = "",
                 checksum: str = "") -> ServedModel:
    """A ServedModel of a validated set: a Φ̃' entry counts as learned when the models it is
    made of are (the base entry's wrench model; a foot's: its leg's joint models)."""
    learned = np.array([m is not None for m in ms.models_], dtype=bool)
    rbd = np.concatenate([learned[:N_BASE]] + [np.repeat(learned[N_BASE + np.asarray(leg)].all(), 3)
                                               for leg in robot.leg_joints])
    return ServedModel(name=name, model_dir=model_dir, model_set=ms, checksum=checksum, rbd_learned=rbd,
                       actuation_learned=learned[ms.n_rbd:], dynamics=RigidBodyDynamics(robot),
                       epsilon=EpsilonFunction(robot, ms))


class SwapHold:
    """When a loaded model may replace the one serving: the first at once, each later one only
    after the current choice (a model, or the model put back by a rollback) has served `hold`
    seconds of reference stamps. With `hold` ≥ the controller's rollback assessment
    (rollback.RollbackConfig.assess) every served model is assessed; without it, snapshots
    arriving every ~5 s replaced at least a quarter of them before their assessment, and a model
    judged against an unjudged predecessor could carry a rise on (results/LIVE_GRAPH.md, seventeenth
    session).

    After a rollback the model put back serves hold × 2^k (k consecutive rollbacks, at most
    MAX_BACKOFF) before the next one is tried: a learner whose snapshots keep failing then costs
    one trial (≤ `hold` of a worse model) per doubling wait, not one per snapshot. k returns to 0
    once a model has served `hold` without being rolled back."""

    MAX_BACKOFF = 4

    def __init__(self, hold: float) -> None:
        self.hold_ns = int(round(hold * 1e9))
        self.since_ns: int | None = None  # first reference stamp served by the current choice
        self.now_ns: int | None = None
        self.changed_once = False          # the nominal model at start is not held
        self.backoff = 0                   # consecutive rollbacks (k)
        self.on_trial = False              # a swapped-in model that has not served `hold` yet

    def reference(self, stamp_ns: int) -> None:
        if self.since_ns is None or stamp_ns < self.since_ns:  # a stamp back in time (a reset) restarts it
            self.since_ns = stamp_ns
        self.now_ns = stamp_ns
        if self.on_trial and stamp_ns - self.since_ns >= self.hold_ns:
            self.on_trial, self.backoff = False, 0  # served its hold without a rollback

    def hold_s(self) -> float:
        """The current choice's hold [s]: `hold`, doubled per rollback in a row for a model put back."""
        return self.hold_ns * 2 ** (0 if self.on_trial else self.backoff) * 1e-9

    def remaining_s(self) -> float:
        """[s] of reference stamps until a loaded model may swap in (0: now)."""
        if not self.changed_once or self.hold_ns <= 0:
            return 0.0
        if self.since_ns is None or self.now_ns is None:
            return self.hold_s()
        return max(0.0, self.hold_s() - (self.now_ns - self.since_ns) * 1e-9)

    def may_swap(self) -> bool:
        return self.remaining_s() <= 0.0

    def swapped(self) -> None:
        """A model was swapped in: on trial; the hold starts again at the next reference."""
        self.changed_once, self.since_ns, self.on_trial = True, None, True

    def rolled_back(self) -> None:
        """The serving model was rolled back: the one put back serves a doubled hold."""
        self.changed_once, self.since_ns, self.on_trial = True, None, False
        self.backoff = min(self.backoff + 1, self.MAX_BACKOFF)


@dataclass
class PredictedError:
    """What the model server publishes on /model_error/predicted.

    Learned model: the set's means and predictive variances [N², Nm²]; observed = the
    dimension has a learned model (an unlearned dimension predicts 0 with its prior
    variance, output_scale², as ModelSet.predict_one does).
    Nominal model (no model loaded, or a non-finite prediction): zeros, all observed
    flags false, and a prior variance from default_scaling(robot): (5 % of the weight
    [N], ×0.1 m [Nm], per foot a quarter; 5 % of each torque limit [Nm])² — large
    compared with a learned model's variance, so "we do not know" is explicit.
    """

    source: str
    rbd_error: np.ndarray
    rbd_variance: np.ndarray
    rbd_observed: np.ndarray
    actuation_error: np.ndarray
    actuation_variance: np.ndarray
    actuation_observed: np.ndarray
    fallback: str | None = None    # why nominal was served ("no_model", "non_finite_prediction")
    generalized_variance: np.ndarray | None = None  # of Φ̃ = J'ᵀΦ̃' (nv), the set's own coordinates


NOMINAL = "nominal"


def nominal_prediction(robot: RobotDescription, fallback: str | None = None) -> PredictedError:
    _, _, out_scale = default_scaling(robot)
    foot = 0.05 * robot.total_mass * 9.81 / robot.n_feet
    rbd_var = np.concatenate([out_scale[:N_BASE], np.full(3 * robot.n_feet, foot)]) ** 2
    nr, nj = len(robot.rbd_error_names), robot.n_joints
    return PredictedError(NOMINAL, np.zeros(nr), rbd_var, np.zeros(nr, bool),
                          np.zeros(nj), out_scale[-nj:] ** 2, np.zeros(nj, bool), fallback,
                          out_scale[:robot.nv] ** 2)


def predict_at_reference(robot: RobotDescription, served: ServedModel | None, ref: ReferenceState,
                         reference_torque: ReferenceTorque | None = None) -> PredictedError:
    """Φ̃' and Γ (with variances) at a reference point (EpsilonFunction.predict: the state's
    learning inputs with the torque τ_ref, τ̇_ref the reference asks for); nominal when no
    model is served or anything predicted is non-finite. Never returns NaN.

    reference_torque: the reference stream's ReferenceTorque (the caller's, so τ̇_ref runs on
    across a model swap; default: the served model's own).
    The set predicts Φ̃ = J'ᵀΦ̃'; Φ̃' = J'⁻ᵀΦ̃ with the basis at qᵈ (eq. 8), its variance
    propagated assuming independent dimensions; Φ̃'s own variance goes along (generalized_variance),
    for the trust gate in the set's coordinates."""
    if served is None:
        return nominal_prediction(robot, "no_model")
    q = np.asarray(ref.q, float)
    # one Jacobian pass per reference: τ_ref's contact Jacobian and the basis share it
    jacobians = served.dynamics.foot_jacobians(q) if np.all(np.isfinite(q)) else None
    out = served.epsilon.predict(ref, reference_torque, jacobians)
    if out is None or jacobians is None:
        return nominal_prediction(robot, "non_finite_reference")
    rbd, rbd_var, gamma, gamma_var = out
    inverse_basis_t = np.linalg.inv(contact_invariant_basis(jacobians, robot.leg_joints).T)
    phi, phi_var = inverse_basis_t @ rbd, inverse_basis_t ** 2 @ rbd_var
    if not all(np.all(np.isfinite(z)) for z in (phi, phi_var, rbd_var, gamma, gamma_var)):
        return nominal_prediction(robot, "non_finite_prediction")
    return PredictedError(served.name, phi, phi_var, served.rbd_learned.copy(), gamma, gamma_var,
                          served.actuation_learned.copy(), generalized_variance=rbd_var)
